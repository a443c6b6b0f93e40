//! Motion leases: a motion with no end of its own (velocity, torque, duty
//! cycle, an interpolated point list) runs only while the client that
//! started it keeps saying so.
//!
//! Not a CiA service but the gateway's policy on top of CiA 402's halt
//! (controlword bit 8, §6.3.1) and quick stop (§6.3.2.1): a profile
//! position or homing move stops by itself at its target, but a velocity
//! set-point keeps a motor turning after the client that wrote it crashed,
//! lost the network or forgot. So such a move is granted a lease of one
//! period; the client renews it (REST or the WebSocket stream) before it
//! runs out, and when it lapses the gateway halts the axis — and quick-stops
//! it if it has not stopped within another period.
//!
//! This module is the table only, sans I/O: time is passed in, ids are
//! made by the caller, and what lapsed is returned for the caller to stop
//! ([`super::leases`] does, on the drive).
//!
//! While a lease is held, the axis belongs to its holder: another client's
//! move is refused (`lease_conflict`) unless it presents the lease. Whatever
//! stops motion (halt, quick stop, STOP ALL, leaving operation enabled) is
//! never refused, and ends the lease.

use std::collections::BTreeMap;
use std::time::Duration;

use tokio::time::Instant;

/// The shortest lease period the gateway grants: a client must be able to
/// renew it over a slow network.
pub const MIN_PERIOD: Duration = Duration::from_millis(200);
/// The longest: a motion nobody watches for a minute is not supervised.
pub const MAX_PERIOD: Duration = Duration::from_secs(60);
/// The default (`--lease-ms`): a dashboard renews every second, and a
/// client that went away stops its axis within three.
pub const DEFAULT_PERIOD: Duration = Duration::from_secs(3);

/// One axis of one node of one bus.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct AxisKey {
    pub bus: String,
    pub node: u8,
    pub axis: u8,
}

impl std::fmt::Display for AxisKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} node {} axis {}", self.bus, self.node, self.axis)
    }
}

/// A lease as granted.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MotionLease {
    /// Unguessable (the caller makes it): whoever presents it holds the axis.
    pub id: String,
    pub axis: AxisKey,
    /// Who started the motion (the token's name, or `anonymous`).
    pub holder: String,
    /// The move's mode (`velocity`, ...), for messages and the audit log.
    pub mode: String,
    pub period: Duration,
    pub expires: Instant,
    /// The stream session that renews it, if any: when that session ends,
    /// the lease lapses at once rather than a period later.
    pub session: Option<u64>,
}

impl MotionLease {
    /// The time left at `now` (zero once expired).
    pub fn remaining(&self, now: Instant) -> Duration {
        self.expires.saturating_duration_since(now)
    }
}

/// Why a lease operation was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LeaseError {
    /// The axis is held by a lease the request did not present.
    #[error(
        "{axis} is held by a {mode} motion of {holder} (lease expires in {} ms): \
         present its lease, or halt or stop the axis first",
        .remaining.as_millis()
    )]
    Conflict {
        axis: AxisKey,
        holder: String,
        mode: String,
        remaining: Duration,
    },
    /// No lease has this id: it lapsed (and its axis was stopped), was
    /// ended by a stop, or never existed.
    #[error(
        "no motion lease '{0}' is held: it lapsed or was ended by a stop \
         (the axis was halted), or it never existed"
    )]
    Unknown(String),
}

/// Every lease held, by axis.
#[derive(Debug, Default)]
pub struct LeaseTable {
    by_axis: BTreeMap<AxisKey, MotionLease>,
}

impl LeaseTable {
    pub fn new() -> Self {
        Self::default()
    }

    /// The lease on `axis`, if one is held at `now`.
    pub fn get(&self, axis: &AxisKey, now: Instant) -> Option<&MotionLease> {
        self.by_axis.get(axis).filter(|lease| lease.expires > now)
    }

    pub fn len(&self) -> usize {
        self.by_axis.len()
    }

    pub fn is_empty(&self) -> bool {
        self.by_axis.is_empty()
    }

    /// Whether a request that presents `presented` (or nothing) may command
    /// motion on `axis` at `now`: yes when no lease is held or it presents
    /// the one held.
    pub fn check(
        &self,
        axis: &AxisKey,
        presented: Option<&str>,
        now: Instant,
    ) -> Result<(), LeaseError> {
        match self.get(axis, now) {
            Some(lease) if Some(lease.id.as_str()) != presented => Err(LeaseError::Conflict {
                axis: axis.clone(),
                holder: lease.holder.clone(),
                mode: lease.mode.clone(),
                remaining: lease.remaining(now),
            }),
            _ => Ok(()),
        }
    }

    /// Grants a lease on `axis` for a motion that needs one: the one held,
    /// renewed, when the request presents it (the holder changing its
    /// set-point), else a new one with `fresh_id`. Refused when another
    /// lease is held and not presented.
    #[allow(clippy::too_many_arguments)]
    pub fn grant(
        &mut self,
        axis: AxisKey,
        presented: Option<&str>,
        fresh_id: String,
        holder: &str,
        mode: &str,
        period: Duration,
        now: Instant,
    ) -> Result<MotionLease, LeaseError> {
        self.check(&axis, presented, now)?;
        let (id, session) = match self.get(&axis, now) {
            Some(held) => (held.id.clone(), held.session),
            None => (fresh_id, None),
        };
        let lease = MotionLease {
            id,
            axis: axis.clone(),
            holder: holder.to_string(),
            mode: mode.to_string(),
            period,
            expires: now + period,
            session,
        };
        self.by_axis.insert(axis, lease.clone());
        Ok(lease)
    }

    /// Renews the lease `id` for another period from `now`; `session`, when
    /// given, binds it to that stream session.
    pub fn renew(
        &mut self,
        id: &str,
        session: Option<u64>,
        now: Instant,
    ) -> Result<MotionLease, LeaseError> {
        let lease = self
            .by_axis
            .values_mut()
            .find(|lease| lease.id == id && lease.expires > now)
            .ok_or_else(|| LeaseError::Unknown(id.to_string()))?;
        lease.expires = now + lease.period;
        if session.is_some() {
            lease.session = session;
        }
        Ok(lease.clone())
    }

    /// Ends the lease on `axis` (its motion was stopped), returning it.
    pub fn release(&mut self, axis: &AxisKey) -> Option<MotionLease> {
        self.by_axis.remove(axis)
    }

    /// Ends the lease `id`, returning it (unknown: an error).
    pub fn release_id(&mut self, id: &str) -> Result<MotionLease, LeaseError> {
        let axis = self
            .by_axis
            .values()
            .find(|lease| lease.id == id)
            .map(|lease| lease.axis.clone())
            .ok_or_else(|| LeaseError::Unknown(id.to_string()))?;
        Ok(self.by_axis.remove(&axis).expect("found just now"))
    }

    /// Ends every lease (STOP ALL, shutdown), returning them.
    pub fn release_all(&mut self) -> Vec<MotionLease> {
        std::mem::take(&mut self.by_axis).into_values().collect()
    }

    /// Takes out every lease that expired by `now`: their axes must be
    /// stopped.
    pub fn lapsed(&mut self, now: Instant) -> Vec<MotionLease> {
        let gone: Vec<AxisKey> = self
            .by_axis
            .values()
            .filter(|lease| lease.expires <= now)
            .map(|lease| lease.axis.clone())
            .collect();
        gone.iter()
            .filter_map(|axis| self.by_axis.remove(axis))
            .collect()
    }

    /// The stream session `session` ended: its leases expire now (the next
    /// [`Self::lapsed`] takes them).
    pub fn session_ended(&mut self, session: u64, now: Instant) -> usize {
        let mut count = 0;
        for lease in self.by_axis.values_mut() {
            if lease.session == Some(session) {
                lease.expires = lease.expires.min(now);
                count += 1;
            }
        }
        count
    }

    /// When the next lease expires.
    pub fn next_expiry(&self) -> Option<Instant> {
        self.by_axis.values().map(|lease| lease.expires).min()
    }
}

#[cfg(test)]
mod tests;
