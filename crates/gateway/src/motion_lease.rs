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
//!
//! A lease is bound to its holder, the identity that took it (a token's
//! name; `anonymous` on a gateway without tokens, where the id alone is the
//! credential): presenting or renewing it as anyone else is refused
//! (`lease_conflict`), even with the right id. The one way past is an
//! explicit take-over ([`LeaseTable::take_over`]): the lease ends, its id
//! is refused from then on, and the new holder gets a lease of its own.
//! Lease ids are secrets: wherever they are logged or shown to others they
//! are [`mask`]ed.

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

/// A lease id as logs and the audit log show it: its first 4 characters
/// and an ellipsis (enough to tell two leases apart, not to use one).
pub fn mask(id: &str) -> String {
    let shown: String = id.chars().take(4).collect();
    format!("{shown}…")
}

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
    /// When a renewal of it was last written to the audit log (stream
    /// renewals are audited at most once per `audit_due` interval).
    pub audited: Option<Instant>,
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
    /// The lease presented is held, by someone else: a lease is renewed and
    /// used by its holder only.
    #[error(
        "motion lease '{masked}' on {axis} is held by {holder}, not {by}: only its \
         holder renews or uses it (an operator may take the axis over with \
         Candeck-Lease-Takeover: true, which is audited)",
        masked = mask(.id)
    )]
    NotHolder {
        id: String,
        axis: AxisKey,
        holder: String,
        by: String,
    },
    /// No lease has this id: it lapsed (and its axis was stopped), was
    /// ended by a stop or a take-over, or never existed.
    #[error(
        "no motion lease '{masked}' is held: it lapsed, was ended by a stop \
         (the axis was halted) or taken over, or it never existed",
        masked = mask(.0)
    )]
    Unknown(String),
    /// A lease id its caller chose (MQTT, where the id is the capability)
    /// names the lease held on another axis: the id must name one lease.
    #[error(
        "motion lease id '{masked}' is held on {axis}: choose one id per axis",
        masked = mask(.id)
    )]
    IdInUse { id: String, axis: AxisKey },
}

/// Every lease held, by axis.
#[derive(Debug, Default)]
pub(crate) struct LeaseTable {
    by_axis: BTreeMap<AxisKey, MotionLease>,
}

impl LeaseTable {
    pub(crate) fn new() -> Self {
        Self::default()
    }

    /// The lease on `axis`, if one is held at `now`.
    pub(crate) fn get(&self, axis: &AxisKey, now: Instant) -> Option<&MotionLease> {
        self.by_axis.get(axis).filter(|lease| lease.expires > now)
    }

    pub(crate) fn len(&self) -> usize {
        self.by_axis.len()
    }

    /// Whether a request of `by` that presents `presented` (or nothing) may
    /// command motion on `axis` at `now`: yes when no lease is held, or its
    /// holder presents the one held.
    pub(crate) fn check(
        &self,
        axis: &AxisKey,
        presented: Option<&str>,
        by: &str,
        now: Instant,
    ) -> Result<(), LeaseError> {
        match self.get(axis, now) {
            Some(lease) if Some(lease.id.as_str()) != presented => Err(LeaseError::Conflict {
                axis: axis.clone(),
                holder: lease.holder.clone(),
                mode: lease.mode.clone(),
                remaining: lease.remaining(now),
            }),
            Some(lease) if lease.holder != by => Err(LeaseError::NotHolder {
                id: lease.id.clone(),
                axis: axis.clone(),
                holder: lease.holder.clone(),
                by: by.to_string(),
            }),
            _ => Ok(()),
        }
    }

    /// Grants a lease on `axis` for a motion that needs one: the one held,
    /// renewed, when the request presents it (the holder changing its
    /// set-point), else a new one with `fresh_id` for `holder`. Refused when
    /// another lease is held and not presented by its holder, or when
    /// `fresh_id` (chosen by the caller) is the id of a lease held on
    /// another axis: ids are looked up alone when renewed or lapsed.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn grant(
        &mut self,
        axis: AxisKey,
        presented: Option<&str>,
        fresh_id: String,
        holder: &str,
        mode: &str,
        period: Duration,
        now: Instant,
    ) -> Result<MotionLease, LeaseError> {
        self.check(&axis, presented, holder, now)?;
        let (id, session, audited) = match self.get(&axis, now) {
            Some(held) => (held.id.clone(), held.session, held.audited),
            None => {
                if let Some(other) = self.by_axis.values().find(|lease| lease.id == fresh_id) {
                    return Err(LeaseError::IdInUse {
                        id: fresh_id,
                        axis: other.axis.clone(),
                    });
                }
                (fresh_id, None, None)
            }
        };
        let lease = MotionLease {
            id,
            axis: axis.clone(),
            holder: holder.to_string(),
            mode: mode.to_string(),
            period,
            expires: now + period,
            session,
            audited,
        };
        self.by_axis.insert(axis, lease.clone());
        Ok(lease)
    }

    /// Renews the lease `id` for another period from `now`, for `by`, its
    /// holder (`None`: the gateway itself, for a request that holds it
    /// while it runs); `session`, when given, binds it to that stream
    /// session.
    pub(crate) fn renew(
        &mut self,
        id: &str,
        by: Option<&str>,
        session: Option<u64>,
        now: Instant,
    ) -> Result<MotionLease, LeaseError> {
        let lease = self
            .by_axis
            .values_mut()
            .find(|lease| lease.id == id && lease.expires > now)
            .ok_or_else(|| LeaseError::Unknown(id.to_string()))?;
        if let Some(by) = by
            && lease.holder != by
        {
            return Err(LeaseError::NotHolder {
                id: id.to_string(),
                axis: lease.axis.clone(),
                holder: lease.holder.clone(),
                by: by.to_string(),
            });
        }
        lease.expires = now + lease.period;
        if session.is_some() {
            lease.session = session;
        }
        Ok(lease.clone())
    }

    /// An explicit take-over of `axis`: the lease held on it (if any) ends
    /// and is returned, for the audit log to name its holder; its id is
    /// refused from then on. The axis keeps moving: the new holder's
    /// command takes it from here.
    pub(crate) fn take_over(&mut self, axis: &AxisKey, now: Instant) -> Option<MotionLease> {
        self.get(axis, now)?;
        self.by_axis.remove(axis)
    }

    /// Whether a renewal of the lease `id` at `now` is to be audited: the
    /// first one, then at most one per `every` (a client renews every
    /// second or so; the audit log must not fill with them). Marks it
    /// audited when it is.
    pub(crate) fn audit_due(&mut self, id: &str, every: Duration, now: Instant) -> bool {
        let Some(lease) = self.by_axis.values_mut().find(|lease| lease.id == id) else {
            return false;
        };
        let due = lease
            .audited
            .is_none_or(|last| now.saturating_duration_since(last) >= every);
        if due {
            lease.audited = Some(now);
        }
        due
    }

    /// Ends the lease on `axis` (its motion was stopped), returning it.
    pub(crate) fn release(&mut self, axis: &AxisKey) -> Option<MotionLease> {
        self.by_axis.remove(axis)
    }

    /// The leases held on the axes of `node` of `bus` (lapsed or not).
    pub(crate) fn on_node(&self, bus: &str, node: u8) -> Vec<MotionLease> {
        self.by_axis
            .values()
            .filter(|lease| lease.axis.bus == bus && lease.axis.node == node)
            .cloned()
            .collect()
    }

    /// Ends the lease `id`, returning it (unknown: an error).
    pub(crate) fn release_id(&mut self, id: &str) -> Result<MotionLease, LeaseError> {
        let axis = self
            .by_axis
            .values()
            .find(|lease| lease.id == id)
            .map(|lease| lease.axis.clone())
            .ok_or_else(|| LeaseError::Unknown(id.to_string()))?;
        Ok(self.by_axis.remove(&axis).expect("found just now"))
    }

    /// Ends every lease (STOP ALL, shutdown), returning them.
    pub(crate) fn release_all(&mut self) -> Vec<MotionLease> {
        std::mem::take(&mut self.by_axis).into_values().collect()
    }

    /// Takes out every lease that expired by `now`: their axes must be
    /// stopped.
    pub(crate) fn lapsed(&mut self, now: Instant) -> Vec<MotionLease> {
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
    pub(crate) fn session_ended(&mut self, session: u64, now: Instant) -> usize {
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
    pub(crate) fn next_expiry(&self) -> Option<Instant> {
        self.by_axis.values().map(|lease| lease.expires).min()
    }
}

#[cfg(test)]
mod tests;
