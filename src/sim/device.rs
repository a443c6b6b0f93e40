//! The device core every virtual product shares (CiA 301): the NMT slave
//! with its boot-up message, the heartbeat producer configured by 0x1017, and
//! the SDO server over the device's [`ObjectStore`], each running only in the
//! NMT states that allow it (the UniSwarm manual's figure 3.9). Resets reload
//! parameters: reset node the whole dictionary, reset communication the
//! communication area 0x1000–0x1FFF, each from the saved values where there
//! are any and from the factory defaults otherwise.
//!
//! Store and restore follow the UMC manual (§9.1.8, §9.1.9): writing the
//! signature `save` (0x65766173) to 0x1010 sub 1–4 saves the writable
//! parameters of all areas, the communication area (0x1000–0x1FFF), the
//! standardized area (0x6000–0x9FFF) or the manufacturer area
//! (0x2000–0x5FFF); writing `load` (0x64616F6C) to 0x1011 sub 1–4 brings back
//! the factory values of those areas, to sub 5–8 the saved values. Both only
//! in pre-operational (abort 0x08000021 otherwise); another value is refused
//! with 0x08000020.
//!
//! Like the protocol layer it does no I/O: frames and the current time go in,
//! frames and a deadline come out. [`run_device`] drives it on a bus.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

use crate::can::{Bus, CanId, Frame, FrameReceiver, RecvError};
use crate::canopen::NodeId;
use crate::canopen::cob::Function;
use crate::canopen::heartbeat::HeartbeatProducer;
use crate::canopen::nmt::{NmtEvent, NmtService, NmtSlave, NmtState};
use crate::canopen::od::{ObjectDictionary, Value};
use crate::canopen::sdo::{AbortCode, ObjectAccess, SdoServer, ServerConfig};

use super::objects::{ObjectStore, StoreError};
use super::persist::write_saved;

/// 0x1017: producer heartbeat time, in ms.
const PRODUCER_HEARTBEAT_TIME: u16 = 0x1017;
/// 0x1010: store parameters.
const STORE_PARAMETERS: u16 = 0x1010;
/// 0x1011: restore default parameters.
const RESTORE_PARAMETERS: u16 = 0x1011;
/// "save" as a little-endian UNSIGNED32.
const SAVE_SIGNATURE: [u8; 4] = *b"save";
/// "load" as a little-endian UNSIGNED32.
const LOAD_SIGNATURE: [u8; 4] = *b"load";

/// The parameter areas of store and restore, by sub-index 1–4.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Area {
    All,
    Communication,
    Standardized,
    Manufacturer,
}

impl Area {
    fn of_sub(sub: u8) -> Option<Area> {
        match sub {
            1 => Some(Area::All),
            2 => Some(Area::Communication),
            3 => Some(Area::Standardized),
            4 => Some(Area::Manufacturer),
            _ => None,
        }
    }

    fn contains(self, index: u16) -> bool {
        match self {
            Area::All => true,
            Area::Communication => (0x1000..=0x1FFF).contains(&index),
            Area::Standardized => (0x6000..=0x9FFF).contains(&index),
            Area::Manufacturer => (0x2000..=0x5FFF).contains(&index),
        }
    }
}

/// Saved parameter values, by index and sub-index.
pub type SavedValues = BTreeMap<(u16, u8), Value>;

/// One virtual CANopen node. See the module documentation.
pub struct DeviceCore {
    /// The factory values.
    defaults: ObjectStore,
    /// What 0x1010 saved; a reset loads these over the factory values.
    saved: SavedValues,
    /// Changes whenever `saved` does, so that a runner knows to persist it.
    saved_version: u64,
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
            saved: SavedValues::new(),
            saved_version: 0,
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

    /// The values 0x1010 saved (to keep them across a restart).
    pub fn saved(&self) -> &SavedValues {
        &self.saved
    }

    /// A number that changes whenever [`DeviceCore::saved`] does.
    pub fn saved_version(&self) -> u64 {
        self.saved_version
    }

    /// Takes values saved before a restart; they are in force from the next
    /// boot, as after a power cycle.
    pub fn load_saved(&mut self, saved: SavedValues) {
        self.saved = saved;
        self.store = self.defaults.clone();
        self.apply_saved(Area::All);
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
                self.apply_saved(Area::All);
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
            let mut access = DeviceAccess {
                state: self.nmt.state(),
                store: &mut self.store,
                defaults: &self.defaults,
                saved: &mut self.saved,
                saved_version: &mut self.saved_version,
            };
            let replies = self.sdo.handle_frame(frame, now, &mut access);
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
        copy_area(&self.defaults, &mut self.store, Area::Communication);
        self.apply_saved(Area::Communication);
    }

    fn apply_saved(&mut self, area: Area) {
        for ((index, sub), value) in &self.saved {
            if area.contains(*index) {
                let _ = self.store.set(*index, *sub, value.clone());
            }
        }
    }
}

/// Copies every value of `area` from `from` to `to`.
fn copy_area(from: &ObjectStore, to: &mut ObjectStore, area: Area) {
    for object in from.dictionary().objects.values() {
        if !area.contains(object.index) {
            continue;
        }
        for sub in object.subs.keys() {
            if let Some(value) = from.get(object.index, *sub) {
                let _ = to.set(object.index, *sub, value.clone());
            }
        }
    }
}

/// The dictionary as the SDO server of a device sees it: the store, with
/// 0x1010 and 0x1011 acting instead of storing what is written.
struct DeviceAccess<'a> {
    state: NmtState,
    store: &'a mut ObjectStore,
    defaults: &'a ObjectStore,
    saved: &'a mut SavedValues,
    saved_version: &'a mut u64,
}

impl DeviceAccess<'_> {
    fn is_command(index: u16, sub: u8) -> bool {
        matches!(index, STORE_PARAMETERS | RESTORE_PARAMETERS) && sub >= 1
    }

    fn save(&mut self, area: Area) {
        *self.saved_version += 1;
        self.saved.retain(|(index, _), _| !area.contains(*index));
        for object in self.store.dictionary().objects.values() {
            if !area.contains(object.index) {
                continue;
            }
            for (sub, entry) in &object.subs {
                // Parameters are what can be written; status values are not saved.
                let is_command = Self::is_command(object.index, *sub);
                if entry.access.is_writable()
                    && !is_command
                    && let Some(value) = self.store.get(object.index, *sub)
                {
                    self.saved.insert((object.index, *sub), value.clone());
                }
            }
        }
    }

    fn restore_factory(&mut self, area: Area) {
        *self.saved_version += 1;
        self.saved.retain(|(index, _), _| !area.contains(*index));
        copy_area(self.defaults, self.store, area);
    }

    fn restore_saved(&mut self, area: Area) {
        for ((index, sub), value) in self.saved.iter() {
            if area.contains(*index) {
                let _ = self.store.set(*index, *sub, value.clone());
            }
        }
    }
}

impl ObjectAccess for DeviceAccess<'_> {
    fn read(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, AbortCode> {
        self.store.read(index, sub)
    }

    fn check_write(&mut self, index: u16, sub: u8, size: Option<usize>) -> Result<(), AbortCode> {
        self.store.check_write(index, sub, size)?;
        if Self::is_command(index, sub) && self.state != NmtState::PreOperational {
            return Err(AbortCode::CannotStoreLocalControl);
        }
        Ok(())
    }

    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
        if !Self::is_command(index, sub) {
            return self.store.write(index, sub, data);
        }
        self.check_write(index, sub, Some(data.len()))?;
        match (index, data) {
            (STORE_PARAMETERS, signature) if signature == SAVE_SIGNATURE => {
                let area = Area::of_sub(sub).ok_or(AbortCode::SubIndexDoesNotExist)?;
                self.save(area);
                Ok(())
            }
            (RESTORE_PARAMETERS, signature) if signature == LOAD_SIGNATURE => {
                match (Area::of_sub(sub), sub.checked_sub(4).and_then(Area::of_sub)) {
                    (Some(area), _) => self.restore_factory(area),
                    (None, Some(area)) => self.restore_saved(area),
                    (None, None) => return Err(AbortCode::SubIndexDoesNotExist),
                }
                Ok(())
            }
            // 0 and 1 configure the automatic restore of 0x1011 (table 3.22).
            (RESTORE_PARAMETERS, [0 | 1, 0, 0, 0]) => self.store.write(index, sub, data),
            _ => Err(AbortCode::CannotStore),
        }
    }

    fn fixed_size(&mut self, index: u16, sub: u8) -> Option<usize> {
        self.store.fixed_size(index, sub)
    }
}

/// Runs `device` on `bus` until the bus closes: boots it, then answers and
/// produces. The device stays shared so that its behaviour (or a test)
/// changes it while it runs. It listens from the moment this is called.
pub fn run_device(bus: Bus, device: Arc<Mutex<DeviceCore>>) -> impl Future<Output = ()> + Send {
    let frames = bus.subscribe();
    drive(bus, frames, device, None)
}

/// [`run_device`], writing the saved values to `path` each time they change
/// (see [`super::persist`]).
pub fn run_persistent_device(
    bus: Bus,
    device: Arc<Mutex<DeviceCore>>,
    path: PathBuf,
) -> impl Future<Output = ()> + Send {
    let frames = bus.subscribe();
    drive(bus, frames, device, Some(path))
}

async fn drive(
    bus: Bus,
    mut frames: FrameReceiver,
    device: Arc<Mutex<DeviceCore>>,
    persist: Option<PathBuf>,
) {
    let mut persisted_version = lock(&device).saved_version();
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
        if let Some(path) = &persist {
            let saved = {
                let device = lock(&device);
                (device.saved_version() != persisted_version)
                    .then(|| (device.saved_version(), device.saved().clone()))
            };
            if let Some((version, saved)) = saved {
                persisted_version = version;
                // A device whose flash fails still runs; the log says so.
                if let Err(err) = write_saved(path, &saved) {
                    tracing::warn!("virtual device: {err}");
                }
            }
        }
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
    use crate::canopen::sdo::{ClientConfig, SdoError};
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

    const SAVE: [u8; 4] = *b"save";
    const LOAD: [u8; 4] = *b"load";

    #[tokio::test(start_paused = true)]
    async fn saved_parameters_survive_a_reset_node() {
        let rig = rig();
        rig.sdo.download(0x2001, 0, &[42]).await.unwrap();
        rig.sdo.download(0x1010, 1, &SAVE).await.unwrap();
        rig.sdo.download(0x2001, 0, &[43]).await.unwrap();
        nmt(&rig.master, NmtCommand::ResetNode).await;
        assert_eq!(rig.sdo.upload(0x2001, 0).await.unwrap(), vec![42]);
        // Reading 0x1010 still tells what the device can do, not the signature.
        assert_eq!(rig.sdo.upload(0x1010, 1).await.unwrap(), 1u32.to_le_bytes());
        // And the values are there for a restart.
        assert_eq!(
            lock(&rig.device).saved().get(&(0x2001, 0)),
            Some(&Value::Unsigned8(42))
        );
        rig.task.abort();
    }

    #[tokio::test(start_paused = true)]
    async fn store_and_restore_only_in_pre_operational_with_the_right_signature() {
        let rig = rig();
        let wrong = rig.sdo.download(0x1010, 1, b"evas").await.unwrap_err();
        assert_eq!(wrong.device_abort(), Some(AbortCode::CannotStore));
        let wrong = rig.sdo.download(0x1011, 1, b"save").await.unwrap_err();
        assert_eq!(wrong.device_abort(), Some(AbortCode::CannotStore));
        nmt(&rig.master, NmtCommand::Start).await;
        let refused = rig.sdo.download(0x1010, 1, &SAVE).await.unwrap_err();
        assert_eq!(
            refused.device_abort(),
            Some(AbortCode::CannotStoreLocalControl)
        );
        let refused = rig.sdo.download(0x1011, 1, &LOAD).await.unwrap_err();
        assert_eq!(
            refused.device_abort(),
            Some(AbortCode::CannotStoreLocalControl)
        );
        rig.task.abort();
    }

    #[tokio::test(start_paused = true)]
    async fn areas_are_saved_and_restored_apart() {
        let rig = rig();
        // A communication parameter and a manufacturer parameter.
        rig.sdo
            .download(0x1017, 0, &200u16.to_le_bytes())
            .await
            .unwrap();
        rig.sdo.download(0x2001, 0, &[42]).await.unwrap();
        // Save only the manufacturer area.
        rig.sdo.download(0x1010, 4, &SAVE).await.unwrap();
        nmt(&rig.master, NmtCommand::ResetNode).await;
        assert_eq!(rig.sdo.upload(0x2001, 0).await.unwrap(), vec![42]);
        assert_eq!(rig.sdo.upload(0x1017, 0).await.unwrap(), vec![0, 0]);
        // Factory values of the manufacturer area, now and after a reset.
        rig.sdo.download(0x1011, 4, &LOAD).await.unwrap();
        assert_eq!(rig.sdo.upload(0x2001, 0).await.unwrap(), vec![7]);
        nmt(&rig.master, NmtCommand::ResetNode).await;
        assert_eq!(rig.sdo.upload(0x2001, 0).await.unwrap(), vec![7]);
        // Restore saved: back to what was saved, without a reset.
        rig.sdo.download(0x2001, 0, &[9]).await.unwrap();
        rig.sdo.download(0x1010, 1, &SAVE).await.unwrap();
        rig.sdo.download(0x2001, 0, &[10]).await.unwrap();
        rig.sdo.download(0x1011, 5, &LOAD).await.unwrap();
        assert_eq!(rig.sdo.upload(0x2001, 0).await.unwrap(), vec![9]);
        rig.task.abort();
    }

    #[test]
    fn values_saved_before_a_restart_are_in_force() {
        let mut device = DeviceCore::new(testnode(), node()).unwrap();
        let mut saved = SavedValues::new();
        saved.insert((0x2001, 0), Value::Unsigned8(55));
        device.load_saved(saved);
        assert_eq!(device.store().get(0x2001, 0), Some(&Value::Unsigned8(55)));
    }

    #[tokio::test(start_paused = true)]
    async fn a_persistent_device_writes_what_it_saves() {
        let dir = std::env::temp_dir().join(format!("candeck-device-{}", std::process::id()));
        let path = super::super::persist::saved_path(&dir, "test", node());
        let _ = std::fs::remove_file(&path);
        let hub = VirtualHub::new("test");
        let master = hub.attach();
        let device = Arc::new(Mutex::new(DeviceCore::new(testnode(), node()).unwrap()));
        let task = tokio::spawn(run_persistent_device(hub.attach(), device, path.clone()));
        let sdo = SdoChannel::new(master.clone(), node(), ClientConfig::default());
        sdo.download(0x2001, 0, &[77]).await.unwrap();
        sdo.download(0x1010, 1, &SAVE).await.unwrap();
        task.abort();
        // A new device, as after a restart of candeck, starts with it.
        let saved = super::super::persist::read_saved(&path).unwrap();
        let mut restarted = DeviceCore::new(testnode(), node()).unwrap();
        restarted.load_saved(saved);
        assert_eq!(
            restarted.store().get(0x2001, 0),
            Some(&Value::Unsigned8(77))
        );
        let _ = std::fs::remove_dir_all(dir);
    }
}
