//! The device core every virtual product shares (CiA 301): the NMT slave
//! with its boot-up message, the heartbeat producer configured by 0x1017, and
//! the SDO server over the device's [`ObjectStore`], each running only in the
//! NMT states that allow it (the UniSwarm manual's figure 3.9). Resets reload
//! parameters: reset node the whole dictionary, reset communication the
//! communication area 0x1000–0x1FFF.
//!
//! Like the protocol layer it does no I/O: frames and the current time go in,
//! frames and a deadline come out. [`run_device`] drives it on a bus.

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

use crate::can::{Bus, CanId, Frame, FrameReceiver, RecvError};
use crate::canopen::NodeId;
use crate::canopen::cob::Function;
use crate::canopen::heartbeat::HeartbeatProducer;
use crate::canopen::nmt::{NmtEvent, NmtService, NmtSlave, NmtState};
use crate::canopen::od::{ObjectDictionary, Value};
use crate::canopen::sdo::{SdoServer, ServerConfig};

use super::objects::{ObjectStore, StoreError};

/// 0x1017: producer heartbeat time, in ms.
const PRODUCER_HEARTBEAT_TIME: u16 = 0x1017;

/// One virtual CANopen node. See the module documentation.
pub struct DeviceCore {
    /// What a reset goes back to.
    defaults: ObjectStore,
    store: ObjectStore,
    nmt: NmtSlave,
    heartbeat: HeartbeatProducer,
    heartbeat_ms: u16,
    sdo: SdoServer,
    sdo_request: CanId,
}

impl DeviceCore {
    /// A node that has not booted yet (see [`DeviceCore::boot`]).
    pub fn new(dictionary: ObjectDictionary, node: NodeId) -> Result<Self, StoreError> {
        let defaults = ObjectStore::new(dictionary, node)?;
        Ok(Self {
            store: defaults.clone(),
            defaults,
            nmt: NmtSlave::new(node),
            heartbeat: HeartbeatProducer::new(node),
            heartbeat_ms: 0,
            sdo: SdoServer::new(node, ServerConfig::default()),
            sdo_request: Function::SdoRx.can_id(node),
        })
    }

    pub fn node(&self) -> NodeId {
        self.nmt.node()
    }

    pub fn nmt_state(&self) -> NmtState {
        self.nmt.state()
    }

    pub fn store(&self) -> &ObjectStore {
        &self.store
    }

    pub fn store_mut(&mut self) -> &mut ObjectStore {
        &mut self.store
    }

    /// Ends initialisation: the boot-up message, then pre-operational with the
    /// heartbeat of 0x1017 running.
    pub fn boot(&mut self, now: Instant) -> Vec<Frame> {
        let boot_up = self.nmt.boot_up();
        self.heartbeat_ms = 0;
        self.follow_heartbeat_time(now);
        vec![boot_up]
    }

    /// Takes a frame from the bus; returns the frames to send.
    pub fn handle_frame(&mut self, frame: &Frame, now: Instant) -> Vec<Frame> {
        match self.nmt.on_frame(frame) {
            Ok(Some(NmtEvent::ResetNode)) => {
                self.store = self.defaults.clone();
                return self.boot(now);
            }
            Ok(Some(NmtEvent::ResetCommunication)) => {
                self.reload_communication_area();
                return self.boot(now);
            }
            Ok(Some(NmtEvent::StateChanged { .. }) | None) => {}
            // A malformed NMT frame is ignored, as devices do.
            Err(_) => return Vec::new(),
        }
        if frame.id() == self.sdo_request && self.nmt.allows(NmtService::Sdo) {
            let replies = self.sdo.handle_frame(frame, now, &mut self.store);
            self.follow_heartbeat_time(now);
            return replies;
        }
        Vec::new()
    }

    /// Timers due at `now`: SDO timeouts and heartbeats.
    pub fn poll(&mut self, now: Instant) -> Vec<Frame> {
        let mut out = Vec::new();
        if self.sdo.deadline().is_some_and(|d| d <= now) {
            out.extend(self.sdo.handle_timeout(now));
        }
        if self.nmt.allows(NmtService::Heartbeat)
            && let Some(frame) = self.heartbeat.poll(now, self.nmt.state())
        {
            out.push(frame);
        }
        out
    }

    /// When [`DeviceCore::poll`] has work next.
    pub fn deadline(&self) -> Option<Instant> {
        [self.sdo.deadline(), self.heartbeat.deadline()]
            .into_iter()
            .flatten()
            .min()
    }

    /// A write to 0x1017 changes the heartbeat from the next period on.
    fn follow_heartbeat_time(&mut self, now: Instant) {
        let period = match self.store.get(PRODUCER_HEARTBEAT_TIME, 0) {
            Some(Value::Unsigned16(ms)) => *ms,
            _ => 0,
        };
        if period != self.heartbeat_ms {
            self.heartbeat_ms = period;
            self.heartbeat.set_period_ms(period, now);
        }
    }

    fn reload_communication_area(&mut self) {
        for object in self.defaults.dictionary().objects.values() {
            if !(0x1000..=0x1FFF).contains(&object.index) {
                continue;
            }
            for sub in object.subs.keys() {
                if let Some(value) = self.defaults.get(object.index, *sub) {
                    let _ = self.store.set(object.index, *sub, value.clone());
                }
            }
        }
    }
}

/// Runs `device` on `bus` until the bus closes: boots it, then answers and
/// produces. The device stays shared so that its behaviour (or a test)
/// changes it while it runs. It listens from the moment this is called.
pub fn run_device(bus: Bus, device: Arc<Mutex<DeviceCore>>) -> impl Future<Output = ()> + Send {
    let frames = bus.subscribe();
    drive(bus, frames, device)
}

async fn drive(bus: Bus, mut frames: FrameReceiver, device: Arc<Mutex<DeviceCore>>) {
    let now = || tokio::time::Instant::now().into_std();
    let boot = lock(&device).boot(now());
    send_all(&bus, boot).await;
    loop {
        let deadline = lock(&device).deadline().map(tokio::time::Instant::from_std);
        let out = tokio::select! {
            received = frames.recv() => match received {
                Ok(frame) => lock(&device).handle_frame(&frame.frame, now()),
                // Requests lost in an overrun end as timeouts, as on a real bus.
                Err(RecvError::Lagged(_)) => continue,
                Err(RecvError::Closed) => return,
            },
            _ = sleep_until(deadline) => lock(&device).poll(now()),
        };
        send_all(&bus, out).await;
    }
}

async fn send_all(bus: &Bus, frames: Vec<Frame>) {
    for frame in frames {
        if let Err(err) = bus.send(frame).await {
            tracing::debug!("virtual device: frame not sent: {err}");
        }
    }
}

fn lock(device: &Mutex<DeviceCore>) -> MutexGuard<'_, DeviceCore> {
    device
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

async fn sleep_until(deadline: Option<tokio::time::Instant>) {
    match deadline {
        Some(deadline) => tokio::time::sleep_until(deadline).await,
        None => std::future::pending().await,
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;
    use crate::can::VirtualHub;
    use crate::canopen::eds::Eds;
    use crate::canopen::nmt::{NmtCommand, NmtMessage, NmtTarget};
    use crate::canopen::sdo::{AbortCode, ClientConfig, SdoError};
    use crate::gateway::sdo::{SdoChannel, SdoRequestError};

    fn node() -> NodeId {
        NodeId::new(5).unwrap()
    }

    fn testnode() -> ObjectDictionary {
        let text = include_str!("../../tests/data/testnode.eds");
        Eds::parse(text, "testnode.eds").unwrap().dictionary
    }

    struct Rig {
        hub: VirtualHub,
        master: Bus,
        device: Arc<Mutex<DeviceCore>>,
        sdo: SdoChannel,
        task: tokio::task::JoinHandle<()>,
    }

    fn rig() -> Rig {
        let hub = VirtualHub::new("test");
        let master = hub.attach();
        let device = Arc::new(Mutex::new(DeviceCore::new(testnode(), node()).unwrap()));
        let task = tokio::spawn(run_device(hub.attach(), device.clone()));
        let config = ClientConfig {
            timeout: Duration::from_millis(200),
            ..ClientConfig::default()
        };
        let sdo = SdoChannel::new(master.clone(), node(), config);
        Rig {
            hub,
            master,
            device,
            sdo,
            task,
        }
    }

    async fn nmt(master: &Bus, command: NmtCommand) {
        let frame = NmtMessage::new(command, NmtTarget::Node(node())).encode();
        master.send(frame).await.unwrap();
        tokio::time::sleep(Duration::from_millis(1)).await;
    }

    #[tokio::test(start_paused = true)]
    async fn a_device_boots_then_answers_sdo_in_pre_operational() {
        let hub = VirtualHub::new("test");
        let master = hub.attach();
        let mut frames = master.subscribe();
        let device = Arc::new(Mutex::new(DeviceCore::new(testnode(), node()).unwrap()));
        let task = tokio::spawn(run_device(hub.attach(), device.clone()));
        let boot_up = frames.recv().await.unwrap().frame;
        assert_eq!(
            (boot_up.id(), boot_up.data()),
            (CanId::Standard(0x705), &[0u8][..])
        );
        assert_eq!(lock(&device).nmt_state(), NmtState::PreOperational);
        let sdo = SdoChannel::new(master.clone(), node(), ClientConfig::default());
        assert_eq!(
            sdo.upload(0x1018, 1).await.unwrap(),
            0x00C4_DEC0u32.to_le_bytes()
        );
        task.abort();
    }

    #[tokio::test(start_paused = true)]
    async fn a_stopped_device_does_not_answer_sdo_until_started() {
        let rig = rig();
        nmt(&rig.master, NmtCommand::Stop).await;
        assert_eq!(lock(&rig.device).nmt_state(), NmtState::Stopped);
        let error = rig.sdo.upload(0x2001, 0).await.unwrap_err();
        assert!(
            matches!(
                error,
                SdoRequestError::Sdo {
                    error: SdoError::Timeout,
                    ..
                }
            ),
            "{error:?}"
        );
        nmt(&rig.master, NmtCommand::Start).await;
        assert_eq!(lock(&rig.device).nmt_state(), NmtState::Operational);
        assert_eq!(rig.sdo.upload(0x2001, 0).await.unwrap(), vec![7]);
        rig.task.abort();
    }

    #[tokio::test(start_paused = true)]
    async fn the_heartbeat_follows_0x1017_with_the_nmt_state() {
        let rig = rig();
        let mut frames = rig.master.subscribe();
        rig.sdo
            .download(0x1017, 0, &100u16.to_le_bytes())
            .await
            .unwrap();
        let start = tokio::time::Instant::now();
        let mut seen = Vec::new();
        while seen.len() < 3 {
            let frame = frames.recv().await.unwrap().frame;
            // The boot-up message (0x00) shares the COB-ID; it is no heartbeat.
            if frame.id() == CanId::Standard(0x705) && frame.data() != [0x00] {
                seen.push((start.elapsed(), frame.data().to_vec()));
            }
        }
        // SDO answers came first; heartbeats then every 100 ms, pre-operational.
        let times: Vec<_> = seen.iter().map(|(t, _)| t.as_millis()).collect();
        assert_eq!(times[1] - times[0], 100);
        assert_eq!(times[2] - times[1], 100);
        assert!(seen.iter().all(|(_, data)| data == &[0x7F]));
        nmt(&rig.master, NmtCommand::Start).await;
        loop {
            let frame = frames.recv().await.unwrap().frame;
            if frame.id() == CanId::Standard(0x705) {
                assert_eq!(frame.data(), &[0x05]);
                break;
            }
        }
        rig.task.abort();
    }

    #[tokio::test(start_paused = true)]
    async fn reset_node_reloads_defaults_and_boots_again() {
        let rig = rig();
        rig.sdo.download(0x2001, 0, &[99]).await.unwrap();
        rig.sdo
            .download(0x1017, 0, &50u16.to_le_bytes())
            .await
            .unwrap();
        let mut frames = rig.master.subscribe();
        nmt(&rig.master, NmtCommand::ResetNode).await;
        loop {
            let frame = frames.recv().await.unwrap().frame;
            if frame.id() == CanId::Standard(0x705) && frame.data() == [0x00] {
                break;
            }
        }
        assert_eq!(rig.sdo.upload(0x2001, 0).await.unwrap(), vec![7]);
        assert_eq!(rig.sdo.upload(0x1017, 0).await.unwrap(), vec![0, 0]);
        rig.task.abort();
    }

    #[tokio::test(start_paused = true)]
    async fn reset_communication_keeps_application_values() {
        let rig = rig();
        rig.sdo.download(0x2001, 0, &[99]).await.unwrap();
        rig.sdo
            .download(0x1017, 0, &50u16.to_le_bytes())
            .await
            .unwrap();
        nmt(&rig.master, NmtCommand::ResetCommunication).await;
        assert_eq!(rig.sdo.upload(0x2001, 0).await.unwrap(), vec![99]);
        assert_eq!(rig.sdo.upload(0x1017, 0).await.unwrap(), vec![0, 0]);
        let refused = rig
            .sdo
            .download(0x1018, 1, &[1, 0, 0, 0])
            .await
            .unwrap_err();
        assert_eq!(refused.device_abort(), Some(AbortCode::ReadOnlyObject));
        drop(rig.hub);
        rig.task.abort();
    }
}
