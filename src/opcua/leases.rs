//! The motion leases of OPC UA sessions. A velocity, torque or duty-cycle
//! `Move` (or halt released in such a mode) over OPC UA is granted a lease
//! by the gateway, as a REST move is; the door binds it to the session that
//! asked: it renews it while the session lives, presents it for the
//! session's later commands on the axis, and lets it lapse the moment the
//! session is closed or times out, so that the gateway's lease supervisor
//! halts the axis, as for a REST client that went away. The lease machinery
//! (grant, renewal, lapse, the halt) is the gateway's; this keeps which
//! session holds which id.

use std::collections::{BTreeMap, HashMap};
use std::sync::Mutex;
use std::time::Duration;

use crate::gateway::{AxisKey, Caller, Gateway, LeaseClaim, MotionLease};

/// Whether a session is still open (closed and timed-out sessions are not).
pub type Alive = Box<dyn Fn() -> bool + Send + Sync>;

/// An open session's leases, to renew: its id, its caller, each axis's lease.
type Renewals = (u32, Caller, Vec<(AxisKey, String)>);

struct Held {
    alive: Alive,
    caller: Caller,
    ids: BTreeMap<AxisKey, String>,
}

/// The leases held by each session, by the server's session id.
#[derive(Default)]
pub struct SessionLeases {
    sessions: Mutex<HashMap<u32, Held>>,
}

impl SessionLeases {
    fn sessions(&self) -> std::sync::MutexGuard<'_, HashMap<u32, Held>> {
        self.sessions
            .lock()
            .unwrap_or_else(|poison| poison.into_inner())
    }

    /// The claim a command of `session` on `axis` presents: the lease the
    /// session holds there, if any.
    pub fn claim(&self, session: u32, axis: &AxisKey) -> LeaseClaim {
        let id = self
            .sessions()
            .get(&session)
            .and_then(|held| held.ids.get(axis).cloned());
        LeaseClaim::presented(id.as_deref(), false)
    }

    /// A command of `session` was granted `lease` (if any): the session
    /// holds it from now on.
    pub fn granted(
        &self,
        session: u32,
        alive: impl FnOnce() -> Alive,
        caller: &Caller,
        lease: Option<&MotionLease>,
    ) {
        let Some(lease) = lease else {
            return;
        };
        let mut sessions = self.sessions();
        let held = sessions.entry(session).or_insert_with(|| Held {
            alive: alive(),
            caller: caller.clone(),
            ids: BTreeMap::new(),
        });
        held.ids.insert(lease.axis.clone(), lease.id.clone());
    }

    /// How many leases sessions hold.
    pub fn len(&self) -> usize {
        self.sessions().values().map(|held| held.ids.len()).sum()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// One round: the leases of sessions that ended lapse now (the gateway
    /// halts their axes); the others are renewed, and those the gateway no
    /// longer holds (a stop ended them) are forgotten. Returns how many
    /// lapsed.
    pub async fn keep(&self, gateway: &Gateway) -> usize {
        let (ended, open): (Vec<_>, Vec<_>) = {
            let mut sessions = self.sessions();
            let ended: Vec<u32> = sessions
                .iter()
                .filter(|(_, held)| !(held.alive)())
                .map(|(id, _)| *id)
                .collect();
            let ended: Vec<Held> = ended
                .into_iter()
                .filter_map(|id| sessions.remove(&id))
                .collect();
            let open: Vec<Renewals> = sessions
                .iter()
                .map(|(id, held)| {
                    let ids = held
                        .ids
                        .iter()
                        .map(|(axis, id)| (axis.clone(), id.clone()))
                        .collect();
                    (*id, held.caller.clone(), ids)
                })
                .collect();
            (ended, open)
        };
        let mut lapsed = 0;
        for held in ended {
            for (axis, id) in &held.ids {
                tracing::warn!(
                    "opcua: the session of {} ended: the motion lease on {axis} lapses now",
                    held.caller.who
                );
                gateway.lapse_lease(id);
                lapsed += 1;
            }
        }
        for (session, caller, ids) in open {
            for (axis, id) in ids {
                if gateway.keep_axis_lease(&caller, &axis, &id).await.is_err() {
                    // Ended by a stop, or taken over: nothing to renew.
                    let mut sessions = self.sessions();
                    if let Some(held) = sessions.get_mut(&session)
                        && held.ids.get(&axis) == Some(&id)
                    {
                        held.ids.remove(&axis);
                    }
                }
            }
        }
        lapsed
    }

    /// Renews and lapses every `period` (a third of the lease period:
    /// two renewals may be lost before the lease lapses) until dropped.
    pub async fn run(self: std::sync::Arc<Self>, gateway: Gateway, period: Duration) {
        let mut tick = tokio::time::interval(period);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tick.tick().await;
            self.keep(&gateway).await;
        }
    }
}
