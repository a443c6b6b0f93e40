//! When a device sends a TPDO (CiA 301 §7.2.2.2, transmission types of
//! §7.5.2.37): the trigger logic of one TPDO as a state machine fed with
//! SYNCs, application events, remote requests and the time.
//!
//! - 0: at the first SYNC after an event (or a remote request).
//! - 1–240: at every nth SYNC. With a SYNC start value, the SYNC whose
//!   counter equals it is the first counted, and sends.
//! - 252: at the first SYNC after a remote request.
//! - 253: at once on a remote request.
//! - 254, 255: at once on an event, a remote request or the event timer,
//!   but never sooner than the inhibit time after the previous one.
//!
//! Type 252 follows the UMC firmware manual (table 3.19: "on RTR received,
//! the sampling will start and will transmit after the next SYNC"); CiA 301
//! words it as sampling at every SYNC and sending on request, which differs
//! only in how old the data is.
//!
//! Every method that can decide to send returns `true` when the device
//! should sample its mapped objects and send the PDO now; the trigger then
//! counts it as sent at that instant (for the inhibit time and event timer).
//! A device feeds the trigger only while operational, and calls
//! [`TpdoTrigger::restart`] on entering operational.

use std::time::Instant;

use super::comm::{PdoCommParams, TransmissionType};

/// The trigger logic of one TPDO.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TpdoTrigger {
    params: PdoCommParams,
    /// Whether a cyclic TPDO counts SYNCs yet (it may wait for the SYNC
    /// start value).
    counting: bool,
    /// SYNCs counted since the last cyclic transmission.
    syncs: u8,
    /// A transmission was asked for and waits: for the next SYNC (types 0,
    /// 252) or for the inhibit time to pass (254, 255).
    pending: bool,
    last_sent: Option<Instant>,
    /// From when the event timer runs: the last transmission, or the start.
    timer_from: Instant,
}

impl TpdoTrigger {
    /// The trigger of a TPDO with `params`, starting at `now`.
    pub fn new(params: PdoCommParams, now: Instant) -> Self {
        Self {
            params,
            counting: false,
            syncs: 0,
            pending: false,
            last_sent: None,
            timer_from: now,
        }
    }

    pub fn params(&self) -> &PdoCommParams {
        &self.params
    }

    /// New parameters (after an SDO write); the trigger starts over at `now`.
    pub fn set_params(&mut self, params: PdoCommParams, now: Instant) {
        *self = Self::new(params, now);
    }

    /// Starts over at `now`, as on entering operational: SYNC counting
    /// restarts (waiting again for the SYNC start value), nothing waits, and
    /// the event timer runs from `now`.
    pub fn restart(&mut self, now: Instant) {
        *self = Self::new(self.params, now);
    }

    fn kind(&self) -> Option<TransmissionType> {
        self.params
            .cob_id
            .valid
            .then_some(self.params.transmission_type)
    }

    fn sent(&mut self, now: Instant) -> bool {
        self.pending = false;
        self.last_sent = Some(now);
        self.timer_from = now;
        true
    }

    fn inhibit_ends(&self) -> Option<Instant> {
        Some(self.last_sent? + self.params.inhibit_time())
    }

    /// An event-driven transmission: now, or when the inhibit time ends.
    fn event_driven(&mut self, now: Instant) -> bool {
        if self.inhibit_ends().is_some_and(|ends| now < ends) {
            self.pending = true;
            return false;
        }
        self.sent(now)
    }

    /// A SYNC was received, with its counter if it has one.
    #[must_use = "when true, the PDO must be sent now"]
    pub fn on_sync(&mut self, counter: Option<u8>, now: Instant) -> bool {
        match self.kind() {
            Some(TransmissionType::SyncAcyclic | TransmissionType::SyncRtr) => {
                self.pending && self.sent(now)
            }
            Some(TransmissionType::SyncCyclic(every)) => {
                if !self.counting {
                    self.counting = true;
                    self.syncs = 0;
                    // The SYNC start value applies only to SYNCs with a
                    // counter; the SYNC that matches it is the first counted,
                    // and goes out at once, as in CANopenNode.
                    if let (start @ 1.., Some(counter)) = (self.params.sync_start, counter) {
                        self.counting = counter == start;
                        return self.counting && self.sent(now);
                    }
                }
                self.syncs = self.syncs.saturating_add(1);
                if self.syncs < every.max(1) {
                    return false;
                }
                self.syncs = 0;
                self.sent(now)
            }
            _ => false,
        }
    }

    /// The application has an event for this PDO (a mapped value changed, or
    /// a device-specific reason). Type 0 sends at the next SYNC, 254 and 255
    /// at once or when the inhibit time ends; other types ignore events.
    #[must_use = "when true, the PDO must be sent now"]
    pub fn on_event(&mut self, now: Instant) -> bool {
        match self.kind() {
            Some(TransmissionType::SyncAcyclic) => {
                self.pending = true;
                false
            }
            Some(kind) if kind.is_event_driven() => self.event_driven(now),
            _ => false,
        }
    }

    /// A remote frame asked for this PDO. Ignored when its COB-ID forbids
    /// remote requests (bit 30), and by cyclic types, which send with their
    /// cycle anyway.
    #[must_use = "when true, the PDO must be sent now"]
    pub fn on_rtr(&mut self, now: Instant) -> bool {
        if !self.params.cob_id.rtr_allowed {
            return false;
        }
        match self.kind() {
            Some(TransmissionType::SyncAcyclic | TransmissionType::SyncRtr) => {
                self.pending = true;
                false
            }
            Some(TransmissionType::AsyncRtr) => self.sent(now),
            Some(kind) if kind.is_event_driven() => self.event_driven(now),
            _ => false,
        }
    }

    /// Whether the event timer or the end of the inhibit time sends the PDO
    /// at `now` (types 254, 255 only).
    #[must_use = "when true, the PDO must be sent now"]
    pub fn poll(&mut self, now: Instant) -> bool {
        if !self.kind().is_some_and(TransmissionType::is_event_driven) {
            return false;
        }
        if self.pending {
            return self.event_driven(now);
        }
        match self.params.event_timer() {
            Some(timer) if now >= self.timer_from + timer => self.event_driven(now),
            _ => false,
        }
    }

    /// When [`poll`](Self::poll) has something to do: the end of the inhibit
    /// time if a transmission waits for it, else the event timer. `None` for
    /// types driven by SYNC or remote requests only.
    pub fn deadline(&self) -> Option<Instant> {
        if !self.kind().is_some_and(TransmissionType::is_event_driven) {
            return None;
        }
        if self.pending {
            return self.inhibit_ends();
        }
        Some(self.timer_from + self.params.event_timer()?)
    }
}

#[cfg(test)]
mod tests;
