//! The I/O of a CiA 401 generic I/O module (profile `cia401`), as
//! operations of the gateway service: every channel with its value and age,
//! and outputs set with a read-back for confirmation ([`Gateway::write_io`],
//! which holds its caller to the policy and writes its audit row, as every
//! bus operation does: [`crate::bus`]). What the objects mean
//! is [`crate::profiles::cia401`].
//!
//! Inputs come from the node's TPDOs where they are mapped (the newest
//! value the gateway decoded, [`super::values`], with its age), else they
//! are read over SDO now (age 0). Outputs are read over SDO: what the
//! device holds, whoever wrote it. A digital output is a bit of an 8-bit
//! group: setting it reads the group, changes the bit and writes the group
//! back, on the node's SDO channel (one transfer at a time); the group is
//! then read again, and the answer says whether the device holds what was
//! asked.

use std::collections::BTreeMap;

use serde_json::Value as Json;
use tokio::time::Instant;

use crate::canopen::od::format_index;
use crate::profiles::cia401::{self, Channel, ChannelKind, Layout, Level};

use super::audit::AuditTarget;
use super::caller::Caller;
use super::error::GatewayError;
use super::policy::Operation;
use super::profile::Profile;
use super::registry::NodeInfo;
use super::sdo::SdoChannel;
use super::service::{Gateway, ServedBus, check_sdo_allowed};

/// One channel's value.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ChannelValue {
    /// `di1`, `ao2`, ...
    pub channel: String,
    /// A boolean for a digital channel, an integer for an analogue one.
    pub value: Json,
    /// How old the value is, ms: since its TPDO came, or 0 when it was
    /// read now.
    pub age_ms: u64,
    /// `tpdo` or `sdo`.
    pub source: &'static str,
}

/// Every channel of a module, by kind.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct IoState {
    pub digital_inputs: Vec<ChannelValue>,
    pub digital_outputs: Vec<ChannelValue>,
    pub analog_inputs: Vec<ChannelValue>,
    pub analog_outputs: Vec<ChannelValue>,
}

/// One output set, and what the device holds after it.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct OutputSet {
    pub channel: String,
    /// What was asked.
    pub written: Json,
    /// What the device answered when read after the write.
    pub read_back: Json,
    /// Whether the two are the same.
    pub confirmed: bool,
}

/// An output value, checked against its channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum OutputValue {
    Digital(bool),
    Analog(i16),
}

impl OutputValue {
    fn json(self) -> Json {
        match self {
            Self::Digital(on) => Json::Bool(on),
            Self::Analog(value) => Json::from(value),
        }
    }
}

/// An SDO read in a task of its own, so that a caller that stops waiting
/// never cuts a transfer halfway.
async fn upload(channel: &SdoChannel, index: u16, sub: u8) -> Result<Vec<u8>, GatewayError> {
    let channel = channel.clone();
    tokio::spawn(async move { channel.upload(index, sub).await })
        .await
        .map_err(|err| GatewayError::Internal(format!("SDO task: {err}")))?
        .map_err(GatewayError::from)
}

async fn download(
    channel: &SdoChannel,
    index: u16,
    sub: u8,
    data: Vec<u8>,
) -> Result<(), GatewayError> {
    let channel = channel.clone();
    tokio::spawn(async move { channel.download(index, sub, &data).await })
        .await
        .map_err(|err| GatewayError::Internal(format!("SDO task: {err}")))?
        .map_err(GatewayError::from)
}

fn byte_of(data: &[u8], index: u16, sub: u8) -> Result<u8, GatewayError> {
    data.first().copied().ok_or_else(|| {
        GatewayError::Internal(format!("{}sub{sub}: an empty answer", format_index(index)))
    })
}

fn word_of(data: &[u8], index: u16, sub: u8) -> Result<i16, GatewayError> {
    match data {
        [low, high, ..] => Ok(i16::from_le_bytes([*low, *high])),
        _ => Err(GatewayError::Internal(format!(
            "{}sub{sub}: {} bytes for an INTEGER16",
            format_index(index),
            data.len()
        ))),
    }
}

/// A module's node after the checks that need no bus.
struct Module {
    served: std::sync::Arc<ServedBus>,
    info: NodeInfo,
    channel: SdoChannel,
}

impl Module {
    /// The channels: from the node's EDS, else from the highest
    /// sub-indices the device reports (0 for an object it lacks).
    async fn layout(&self) -> Result<Layout, GatewayError> {
        if let Some(entry) = &self.info.eds_entry {
            return Ok(Layout::from_dictionary(&entry.eds.dictionary));
        }
        let mut highest = [0u8; 4];
        for (kind, slot) in ChannelKind::ALL.into_iter().zip(highest.iter_mut()) {
            *slot = match upload(&self.channel, kind.index(), 0).await {
                Ok(data) => data.first().copied().unwrap_or(0),
                Err(GatewayError::SdoAbort { .. }) => 0,
                Err(error) => return Err(error),
            };
        }
        let [di, dout, ai, ao] = highest;
        Ok(Layout::from_highest_subs(di, dout, ai, ao))
    }

    /// The bytes of `index` sub `sub`: from a TPDO for inputs when one
    /// carries it, else read now; with their age and source.
    async fn raw(
        &self,
        index: u16,
        sub: u8,
        input: bool,
        now: Instant,
    ) -> Result<(Vec<u8>, u64, &'static str), GatewayError> {
        if input && let Some(value) = self.served.values.value(self.info.id, index, sub) {
            let age = now.saturating_duration_since(value.at).as_millis();
            return Ok((
                value.raw_bytes(),
                u64::try_from(age).unwrap_or(u64::MAX),
                "tpdo",
            ));
        }
        let data = upload(&self.channel, index, sub).await?;
        Ok((data, 0, "sdo"))
    }

    async fn channels(
        &self,
        layout: &Layout,
        kind: ChannelKind,
        now: Instant,
    ) -> Result<Vec<ChannelValue>, GatewayError> {
        let mut values = Vec::new();
        // A digital group (one sub-index) is read once for its 8 channels.
        let mut groups: BTreeMap<u8, (Vec<u8>, u64, &'static str)> = BTreeMap::new();
        for channel in layout.channels(kind) {
            let (index, sub, _) = channel.location();
            let &mut (ref data, age_ms, source) = match groups.entry(sub) {
                std::collections::btree_map::Entry::Occupied(read) => read.into_mut(),
                std::collections::btree_map::Entry::Vacant(slot) => {
                    slot.insert(self.raw(index, sub, !kind.is_output(), now).await?)
                }
            };
            let value = match channel.level_in(data) {
                Some(Level::Digital(on)) => Json::Bool(on),
                Some(Level::Analog(level)) => Json::from(level),
                None => {
                    return Err(GatewayError::Internal(format!(
                        "{}sub{sub}: {} bytes for {channel}",
                        format_index(index),
                        data.len()
                    )));
                }
            };
            values.push(ChannelValue {
                channel: channel.to_string(),
                value,
                age_ms,
                source,
            });
        }
        Ok(values)
    }
}

impl Gateway {
    fn io_module(&self, bus: &str, id: &str) -> Result<Module, GatewayError> {
        let (served, info) = self.node(bus, id)?;
        if info.profile != Profile::Cia401 {
            return Err(GatewayError::NotAnIoModule(format!(
                "node {} is {}, not a CiA 401 I/O module (device type 401)",
                info.id, info.profile
            )));
        }
        check_sdo_allowed(&served, &info)?;
        let channel = served.registry.sdo(info.id)?;
        Ok(Module {
            served,
            info,
            channel,
        })
    }

    /// Every channel of a CiA 401 node with its value and age (see the
    /// module documentation).
    pub async fn read_io(&self, bus: &str, id: &str) -> Result<IoState, GatewayError> {
        let module = self.io_module(bus, id)?;
        let layout = module.layout().await?;
        let now = Instant::now();
        Ok(IoState {
            digital_inputs: module
                .channels(&layout, ChannelKind::DigitalInput, now)
                .await?,
            digital_outputs: module
                .channels(&layout, ChannelKind::DigitalOutput, now)
                .await?,
            analog_inputs: module
                .channels(&layout, ChannelKind::AnalogInput, now)
                .await?,
            analog_outputs: module
                .channels(&layout, ChannelKind::AnalogOutput, now)
                .await?,
        })
    }

    /// Sets outputs of node `id` of `bus` (`do3` → a boolean, `ao1` → an
    /// INTEGER16), each read back (the operator's; one write of the
    /// caller's rate). Every name and value is checked before the first
    /// write: an unknown channel (or an input) is `unknown_channel`, a
    /// value that is no boolean or no INTEGER16 `invalid_value` /
    /// `value_out_of_range`. Audited as `set outputs`; the checks and the
    /// transfers run in a task of their own with the row, so that a client
    /// that goes away cannot leave a group of outputs half set.
    pub async fn write_io(
        &self,
        caller: &Caller,
        bus: &str,
        id: &str,
        outputs: BTreeMap<String, Json>,
    ) -> Result<Vec<OutputSet>, GatewayError> {
        let target = AuditTarget::new("set outputs").node(id.parse::<u8>().ok());
        let summary = serde_json::json!({ "outputs": outputs }).to_string();
        let (gateway, bus_name, id) = (self.clone(), bus.to_string(), id.to_string());
        self.on_bus(
            caller,
            Operation::SetOutputs,
            bus,
            target,
            Some(summary),
            |_| async move { gateway.set_outputs(&bus_name, &id, &outputs).await },
        )
        .await
    }

    async fn set_outputs(
        &self,
        bus: &str,
        id: &str,
        outputs: &BTreeMap<String, Json>,
    ) -> Result<Vec<OutputSet>, GatewayError> {
        let module = self.io_module(bus, id)?;
        if outputs.is_empty() {
            return Err(GatewayError::InvalidRequest(
                "no outputs: give {\"outputs\": {\"do1\": true, \"ao1\": 1000}}".into(),
            ));
        }
        let layout = module.layout().await?;
        let mut checked: Vec<(Channel, OutputValue)> = Vec::new();
        for (name, value) in outputs {
            if Channel::parse(name).is_none()
                && let Some(meant) = Channel::read_loosely(name)
            {
                return Err(GatewayError::InvalidRequest(format!(
                    "'{name}' is not how a channel is named; write '{meant}' (di, do, ai or ao in lowercase, then the number from 1, without leading zeros or spaces)"
                )));
            }
            let channel = Channel::parse(name)
                .filter(|channel| channel.kind.is_output() && layout.contains(*channel))
                .ok_or_else(|| {
                    GatewayError::UnknownChannel(format!(
                        "node {} has no output '{name}' (do1–do{}, ao1–ao{})",
                        module.info.id, layout.digital_outputs, layout.analog_outputs
                    ))
                })?;
            let value = if channel.kind.is_digital() {
                match value {
                    Json::Bool(on) => OutputValue::Digital(*on),
                    Json::Number(n) if n.as_u64() == Some(0) || n.as_u64() == Some(1) => {
                        OutputValue::Digital(n.as_u64() == Some(1))
                    }
                    other => {
                        return Err(GatewayError::InvalidValue(format!(
                            "{channel}: {other} is no boolean"
                        )));
                    }
                }
            } else {
                let number = value.as_i64().ok_or_else(|| {
                    GatewayError::InvalidValue(format!("{channel}: {value} is no integer"))
                })?;
                let word = i16::try_from(number).map_err(|_| {
                    GatewayError::ValueOutOfRange(format!(
                        "{channel}: {number} is outside INTEGER16 (-32768 to 32767)"
                    ))
                })?;
                OutputValue::Analog(word)
            };
            checked.push((channel, value));
        }
        let mut results = Vec::new();
        for (channel, value) in checked {
            let (index, sub, bit) = channel.location();
            let read_back = match (value, bit) {
                (OutputValue::Digital(on), Some(bit)) => {
                    let group = byte_of(&upload(&module.channel, index, sub).await?, index, sub)?;
                    download(
                        &module.channel,
                        index,
                        sub,
                        vec![cia401::with_bit(group, bit, on)],
                    )
                    .await?;
                    let again = byte_of(&upload(&module.channel, index, sub).await?, index, sub)?;
                    OutputValue::Digital(cia401::bit(again, bit))
                }
                (OutputValue::Analog(word), _) => {
                    download(&module.channel, index, sub, word.to_le_bytes().to_vec()).await?;
                    let again = word_of(&upload(&module.channel, index, sub).await?, index, sub)?;
                    OutputValue::Analog(again)
                }
                (OutputValue::Digital(_), None) => {
                    return Err(GatewayError::Internal(format!(
                        "{channel}: a digital channel without a bit"
                    )));
                }
            };
            results.push(OutputSet {
                channel: channel.to_string(),
                written: value.json(),
                read_back: read_back.json(),
                confirmed: read_back == value,
            });
        }
        Ok(results)
    }
}
