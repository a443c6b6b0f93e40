//! The motion leases of OPC UA sessions. A velocity, torque or duty-cycle
//! `Move` (or halt released in such a mode) over OPC UA is granted a lease
//! by the gateway, as a REST move is; the door binds it to the session that
//! asked: it renews it while the session talks, presents it for the
//! session's later commands on the axis, and lets it lapse the moment the
//! session is closed or times out, or has made no request for a lease
//! period (a client that vanished without closing: killed, unplugged), so
//! that the gateway's lease supervisor halts the axis, as for a REST client
//! that went away. Any request counts as talking: a subscribed client's
//! publish requests, a read, a keep-alive read of the server's state. The
//! lease machinery (grant, renewal, lapse, the halt) is the gateway's; this
//! keeps which session holds which id.

use std::collections::{BTreeMap, HashMap};
use std::sync::Mutex;
use std::time::Duration;

use tokio::time::Instant;

use crate::gateway::{AxisKey, Caller, Gateway, LeaseClaim, MotionLease};

/// A mark that moves whenever a session makes a request (async-opcua's
/// session deadline: its last request plus its timeout).
pub type ActivityMark = std::time::Instant;

/// What a session shows now: `None` once it is closed or timed out, else
/// its [`ActivityMark`].
pub type Probe = Box<dyn Fn() -> Option<ActivityMark> + Send + Sync>;

/// An open session's leases, to renew: its id, its caller, each axis's lease.
type Renewals = (u32, Caller, Vec<(AxisKey, String)>);

/// Why a session's leases lapse.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Ended {
    /// Closed, or timed out by the server.
    Closed,
    /// Open, but no request for longer than the lease period.
    Silent,
}

struct Held {
    probe: Probe,
    caller: Caller,
    ids: BTreeMap<AxisKey, String>,
    /// The mark last seen, and when (by the keeper's clock) it last moved.
    mark: Option<ActivityMark>,
    active: Instant,
}

/// The leases held by each session, by the server's session id.
pub struct SessionLeases {
    sessions: Mutex<HashMap<u32, Held>>,
    /// How long a session may make no request and keep its leases: the
    /// gateway's lease period, what a REST client has between renewals.
    silence: Duration,
}

impl SessionLeases {
    /// Leases that lapse after `silence` without a request (the gateway's
    /// lease period).
    pub fn new(silence: Duration) -> Self {
        Self {
            sessions: Mutex::default(),
            silence,
        }
    }

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
        probe: impl FnOnce() -> Probe,
        caller: &Caller,
        lease: Option<&MotionLease>,
    ) {
        let Some(lease) = lease else {
            return;
        };
        let mut sessions = self.sessions();
        let held = sessions.entry(session).or_insert_with(|| {
            let probe = probe();
            Held {
                mark: probe(),
                probe,
                caller: caller.clone(),
                ids: BTreeMap::new(),
                active: Instant::now(),
            }
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

    /// The sessions whose leases lapse now (closed, or silent for longer
    /// than the lease period), taken out; the others' leases, to renew.
    fn sort(&self, now: Instant) -> (Vec<(Held, Ended)>, Vec<Renewals>) {
        let mut sessions = self.sessions();
        let mut ended = Vec::new();
        for (id, held) in sessions.iter_mut() {
            match (held.probe)() {
                None => ended.push((*id, Ended::Closed)),
                Some(mark) => {
                    if held.mark != Some(mark) {
                        held.mark = Some(mark);
                        held.active = now;
                    } else if now.duration_since(held.active) > self.silence {
                        ended.push((*id, Ended::Silent));
                    }
                }
            }
        }
        let ended = ended
            .into_iter()
            .filter_map(|(id, why)| sessions.remove(&id).map(|held| (held, why)))
            .collect();
        let open = sessions
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
    }

    /// One round: the leases of sessions that ended or went silent lapse
    /// now (the gateway halts their axes); the others are renewed, and
    /// those the gateway no longer holds (a stop ended them) are
    /// forgotten. Returns how many lapsed.
    pub async fn keep(&self, gateway: &Gateway) -> usize {
        let (ended, open) = self.sort(Instant::now());
        let mut lapsed = 0;
        for (held, why) in ended {
            let why = match why {
                Ended::Closed => "ended",
                Ended::Silent => "made no request for a lease period",
            };
            for (axis, id) in &held.ids {
                tracing::warn!(
                    "opcua: the session of {} {why}: the motion lease on {axis} lapses now",
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

#[cfg(test)]
mod tests {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicU8, Ordering};

    use super::*;
    use crate::gateway::{Channel, Role};

    const PERIOD: Duration = Duration::from_secs(1);
    const ROUND: Duration = Duration::from_millis(333);

    /// A session as the probe sees it: 0 closed, else a count its requests
    /// move on.
    #[derive(Clone, Default)]
    struct FakeSession(Arc<AtomicU8>);

    impl FakeSession {
        fn open() -> Self {
            let session = Self::default();
            session.request();
            session
        }
        fn request(&self) {
            self.0.fetch_add(1, Ordering::SeqCst);
        }
        fn close(&self) {
            self.0.store(0, Ordering::SeqCst);
        }
        fn probe(&self) -> Probe {
            let (count, epoch) = (self.0.clone(), std::time::Instant::now());
            Box::new(move || match count.load(Ordering::SeqCst) {
                0 => None,
                n => Some(epoch + Duration::from_millis(n.into())),
            })
        }
    }

    fn lease(id: &str) -> MotionLease {
        MotionLease {
            id: id.to_string(),
            axis: AxisKey {
                bus: "demo".to_string(),
                node: 1,
                axis: 1,
            },
            holder: "line-hmi".to_string(),
            mode: "velocity".to_string(),
            period: PERIOD,
            expires: Instant::now() + PERIOD,
            session: None,
            audited: None,
        }
    }

    fn hold(leases: &SessionLeases, session: u32, fake: &FakeSession) {
        let caller = Caller::new(Channel::Opcua, "line-hmi", Some(Role::Operator));
        leases.granted(
            session,
            || fake.probe(),
            &caller,
            Some(&lease(&format!("lease-{session}"))),
        );
    }

    /// The sessions whose leases lapse after a round at `now`.
    fn lapsing(leases: &SessionLeases) -> Vec<(String, Ended)> {
        let (ended, _) = leases.sort(Instant::now());
        ended
            .into_iter()
            .flat_map(|(held, why)| held.ids.into_values().map(move |id| (id, why)))
            .collect()
    }

    #[tokio::test(start_paused = true)]
    async fn a_session_that_stops_talking_loses_its_lease_within_the_lease_period() {
        let leases = SessionLeases::new(PERIOD);
        let (talking, vanished) = (FakeSession::open(), FakeSession::open());
        hold(&leases, 1, &talking);
        hold(&leases, 2, &vanished);
        // Ten lease periods: the talking session keeps its lease, the one
        // that went silent loses it one period after its last request.
        let mut lapsed_at = None;
        for round in 1..=30u32 {
            tokio::time::advance(ROUND).await;
            talking.request();
            let lapsed = lapsing(&leases);
            if !lapsed.is_empty() {
                assert_eq!(lapsed, vec![("lease-2".to_string(), Ended::Silent)]);
                assert!(lapsed_at.is_none(), "lapsed twice");
                lapsed_at = Some(ROUND * round);
            }
        }
        let lapsed_at = lapsed_at.expect("the silent session kept its lease");
        assert!(
            lapsed_at > PERIOD && lapsed_at <= PERIOD + ROUND,
            "{lapsed_at:?}"
        );
        assert_eq!(leases.len(), 1, "the talking session's lease is kept");
    }

    #[tokio::test(start_paused = true)]
    async fn a_closed_session_loses_its_lease_at_the_next_round() {
        let leases = SessionLeases::new(PERIOD);
        let session = FakeSession::open();
        hold(&leases, 7, &session);
        tokio::time::advance(ROUND).await;
        assert!(lapsing(&leases).is_empty());
        session.close();
        assert_eq!(
            lapsing(&leases),
            vec![("lease-7".to_string(), Ended::Closed)]
        );
        assert!(leases.is_empty());
    }

    #[tokio::test(start_paused = true)]
    async fn requests_now_and_then_within_the_lease_period_keep_the_lease() {
        let leases = SessionLeases::new(PERIOD);
        let session = FakeSession::open();
        hold(&leases, 3, &session);
        // One request every 900 ms (a keep-alive read): never a full lease
        // period without one.
        for step in 1..=60u32 {
            tokio::time::advance(Duration::from_millis(100)).await;
            if step % 9 == 0 {
                session.request();
            }
            if step % 3 == 0 {
                assert!(lapsing(&leases).is_empty(), "lapsed at step {step}");
            }
        }
        assert_eq!(leases.len(), 1);
    }
}
