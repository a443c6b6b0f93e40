//! candeck's node manager: the namespace `urn:candeck` in memory, where
//! every method call and every write is one gateway operation with the
//! session's [`Caller`] (channel `opcua`, the token's name and role): the
//! roles, the write limiter, the motion authority and leases, and the audit
//! log are the gateway's; this parses the arguments, calls, and maps the
//! answer ([`super::status::status_of`]). Dictionary, LED and I/O variables
//! are read over SDO when a client reads, and sampled only while monitored
//! ([`super::sampling`]).

use std::sync::Arc;

use async_trait::async_trait;
use opcua::server::CreateMonitoredItem;
use opcua::server::address_space::AddressSpace;
use opcua::server::diagnostics::NamespaceMetadata;
use opcua::server::node_manager::memory::InMemoryNodeManagerImpl;
use opcua::server::node_manager::{
    MethodCall, MonitoredItemRef, MonitoredItemUpdateRef, ParsedReadValueId, RequestContext,
    ServerContext, WriteNode,
};
use opcua::sync::RwLock;
use opcua::types::{AttributeId, DataValue, StatusCode, TimestampsToReturn, Variant};

use super::browse::{self, AxisMethod, NodePath, Target};
use super::feed::AxisDemand;
use super::leases::SessionLeases;
use super::sampling::Watched;
use super::status::{diagnostic_of, status_of};
use super::users::TokenUsers;
use crate::gateway::{
    AxisKey, Caller, DoorDetail, Gateway, GatewayError, MotionFailed, StepTestRequest, TargetState,
};

/// What the node manager works with, shared with the feed.
pub struct Door {
    pub gateway: Gateway,
    pub users: TokenUsers,
    pub leases: Arc<SessionLeases>,
    pub demand: Arc<AxisDemand>,
    /// The monitored dictionary, I/O and LED variables and their nodes'
    /// samplers.
    pub sampling: Arc<super::sampling::Sampling>,
}

/// The node manager of namespace `urn:candeck`.
pub struct CandeckNodes {
    door: Arc<Door>,
    ns: u16,
}

impl CandeckNodes {
    pub fn new(door: Arc<Door>, ns: u16) -> Self {
        Self { door, ns }
    }

    /// The session's caller, for one request `verb` on `node`.
    fn caller(
        &self,
        context: &RequestContext,
        verb: &str,
        node: &str,
        summary: Option<String>,
    ) -> Caller {
        self.door
            .users
            .caller(context.user_token())
            .with_detail(DoorDetail::new(verb, node).summary(summary))
    }

    fn target(&self, id: &opcua::types::NodeId) -> Option<Target> {
        if id.namespace != self.ns {
            return None;
        }
        match &id.identifier {
            opcua::types::Identifier::String(text) => Target::parse(text.as_ref()),
            _ => None,
        }
    }

    /// The LED segment field or I/O channel `id` is, if it is one
    /// ([`super::io`]).
    fn io_variable(&self, id: &opcua::types::NodeId) -> Option<super::io::IoVariable> {
        if id.namespace != self.ns {
            return None;
        }
        match &id.identifier {
            opcua::types::Identifier::String(text) => super::io::IoVariable::parse(text.as_ref()),
            _ => None,
        }
    }

    /// A write of a segment's field or an output: checked by the tree
    /// (access level, type), then the gateway's segment or output write.
    async fn write_io(
        &self,
        context: &RequestContext,
        address_space: &RwLock<AddressSpace>,
        write: &mut WriteNode,
        variable: &super::io::IoVariable,
    ) {
        // An input is no user's to write: not writable, rather than the
        // tree's access-level check's BadUserAccessDenied.
        let input = matches!(variable, super::io::IoVariable::Channel { channel, .. }
            if !channel.kind.is_output());
        if write.value().attribute_id != AttributeId::Value || input {
            write.set_status(StatusCode::BadNotWritable);
            return;
        }
        if let Err(status) = tree_allows(context, address_space, write) {
            write.set_status(status);
            return;
        }
        let value = write.value().value.value.clone().unwrap_or(Variant::Empty);
        let caller = self.caller(
            context,
            "Write",
            &variable.path(),
            super::io::summary(&value),
        );
        match super::io::write(&self.door.gateway, &caller, variable, &value).await {
            Ok(()) => write.set_status(StatusCode::Good),
            Err(error) => {
                write.set_status(status_of(&error));
                write.set_diagnostic_info(diagnostic_of(&error));
            }
        }
    }

    /// One method: the gateway's answer as the method's outputs.
    async fn call_one(
        &self,
        context: &RequestContext,
        target: Target,
        method: &str,
        args: &[Variant],
    ) -> Result<Vec<Variant>, GatewayError> {
        let summary = Some(
            serde_json::Value::Array(
                args.iter()
                    .map(|arg| super::values::json_of(arg).unwrap_or(serde_json::Value::Null))
                    .collect(),
            )
            .to_string(),
        );
        let caller = self.caller(context, "Call", method, summary);
        let gateway = &self.door.gateway;
        match target {
            Target::StopAll => {
                let report = gateway.stop_all(&caller).await?;
                Ok(vec![Variant::UInt32(report.stopped.len() as u32)])
            }
            Target::Acknowledge => {
                let id = string_arg(args, 0, "AlarmId")?;
                let comment = match args.get(1) {
                    None | Some(Variant::Empty) => None,
                    Some(_) => {
                        Some(string_arg(args, 1, "Comment")?).filter(|text| !text.is_empty())
                    }
                };
                let alarm = gateway.acknowledge_alarm(&caller, &id, comment).await?;
                Ok(vec![Variant::String(alarm.state.name().into())])
            }
            Target::Scan { bus } => {
                let found = gateway.scan(&caller, &bus).await?;
                Ok(vec![Variant::UInt32(found.len() as u32)])
            }
            Target::Sync { bus } => {
                let period =
                    std::time::Duration::from_millis(u64::from(uint_arg(args, 0, "PeriodMs")?));
                gateway.set_sync_period(&caller, &bus, period).await?;
                Ok(Vec::new())
            }
            Target::Nmt(node) => {
                let command = browse::nmt_command(&string_arg(args, 0, "Command")?)?;
                handle(gateway, &node)?.nmt(&caller, command).await?;
                Ok(Vec::new())
            }
            Target::Store(node) => {
                let area = browse::parameter_area(&string_arg(args, 0, "Area")?)?;
                handle(gateway, &node)?
                    .store_parameters(&caller, area)
                    .await?;
                Ok(Vec::new())
            }
            Target::Restore(node) => {
                let area = browse::parameter_area(&string_arg(args, 0, "Area")?)?;
                let source = browse::restore_source(&string_arg(args, 1, "Source")?)?;
                handle(gateway, &node)?
                    .restore_parameters(&caller, area, source)
                    .await?;
                Ok(Vec::new())
            }
            Target::Axis { node, axis, method } => {
                self.call_axis(context, &caller, &node, axis, method, args)
                    .await
            }
            Target::Object { .. } => Err(GatewayError::InvalidRequest(
                "a dictionary entry is a variable: read or write it".to_string(),
            )),
        }
    }

    async fn call_axis(
        &self,
        context: &RequestContext,
        caller: &Caller,
        node: &NodePath,
        axis: u8,
        method: AxisMethod,
        args: &[Variant],
    ) -> Result<Vec<Variant>, GatewayError> {
        let gateway = &self.door.gateway;
        let id = node.node.to_string();
        let axis_text = axis.to_string();
        let path = (node.bus.as_str(), id.as_str(), axis_text.as_str());
        let key = AxisKey {
            bus: node.bus.clone(),
            node: node.node,
            axis,
        };
        let session = context.session_id();
        let claim = self.door.leases.claim(session, &key);
        // The session's deadline moves with each of its requests: the
        // lease keeper's sign that the client still talks.
        let probe = || -> super::leases::Probe {
            let weak = Arc::downgrade(&context.session);
            Box::new(move || {
                let session = weak.upgrade()?;
                let session = session.read();
                session.is_activated().then(|| session.deadline())
            })
        };
        let outcome = match method {
            AxisMethod::SetState => {
                let target = browse::target_state(&string_arg(args, 0, "Target")?)?;
                gateway
                    .set_axis_state(caller, path, target, &claim)
                    .await
                    .map_err(failed)?
            }
            AxisMethod::Move => {
                let request = browse::move_request(
                    &string_arg(args, 0, "Mode")?,
                    double_arg(args, 1, "Target")?,
                    double_arg(args, 2, "Velocity")?,
                    double_arg(args, 3, "Acceleration")?,
                    double_arg(args, 4, "Deceleration")?,
                    bool_arg(args, 5, "Relative")?,
                )?;
                let outcome = gateway
                    .move_axis(caller, path, &request, &claim)
                    .await
                    .map_err(failed)?;
                let leased = outcome.lease.is_some();
                self.door
                    .leases
                    .granted(session, probe, caller, outcome.lease.as_ref());
                return Ok(vec![Variant::Boolean(leased)]);
            }
            AxisMethod::Halt => gateway
                .set_axis_halt(caller, path, true, &Default::default())
                .await
                .map_err(failed)?,
            AxisMethod::QuickStop => gateway
                .set_axis_state(
                    caller,
                    path,
                    TargetState::QuickStopActive,
                    &Default::default(),
                )
                .await
                .map_err(failed)?,
            AxisMethod::FaultReset => {
                gateway.reset_axis_fault(caller, path).await?;
                return Ok(Vec::new());
            }
            AxisMethod::TakeLease => {
                let id = claim.id.clone().ok_or_else(|| {
                    GatewayError::UnknownLease(format!(
                        "this session holds no lease on axis {axis} of node {}: a velocity, \
                         torque or duty-cycle Move takes one",
                        node.node
                    ))
                })?;
                // Renewed once as it is handed over: the client's period
                // starts now, and a lease that ended is refused here.
                let lease = gateway.renew_axis_lease(caller, &key, &id).await?;
                return Ok(vec![
                    Variant::String(lease.id.into()),
                    Variant::UInt32(period_ms(lease.period)),
                ]);
            }
            AxisMethod::RenewLease => {
                let id = string_arg(args, 0, "LeaseId")?;
                let lease = gateway.renew_axis_lease(caller, &key, &id).await?;
                return Ok(vec![Variant::UInt32(period_ms(lease.period))]);
            }
            AxisMethod::ReleaseLease => {
                let id = string_arg(args, 0, "LeaseId")?;
                gateway.give_up_axis_lease(caller, &key, &id).await?;
                return Ok(Vec::new());
            }
            AxisMethod::StepTest => {
                let text = string_arg(args, 0, "Request")?;
                let request: StepTestRequest = serde_json::from_str(&text).map_err(|err| {
                    GatewayError::InvalidRequest(format!(
                        "Request is the JSON body of REST's step test: {err}"
                    ))
                })?;
                let outcome = gateway
                    .step_test_axis(caller, path, &request, &claim)
                    .await
                    .map_err(failed)?;
                let result = serde_json::to_string(&outcome.status)
                    .map_err(|err| GatewayError::Internal(err.to_string()))?;
                return Ok(vec![Variant::String(result.into())]);
            }
        };
        self.door
            .leases
            .granted(session, probe, caller, outcome.lease.as_ref());
        Ok(Vec::new())
    }

    /// A dictionary entry read over SDO now.
    async fn read_object(
        &self,
        context: &RequestContext,
        node: &NodePath,
        index: u16,
        sub: u8,
    ) -> DataValue {
        let caller = self.caller(context, "Read", &node.object(index, sub), None);
        super::sampling::read_entry(&self.door.gateway, &caller, node, index, sub).await
    }

    /// What a monitored item on `id` watches when its node's sampler
    /// samples it: a dictionary variable, a channel or a segment field;
    /// `None` for the other variables. With its path, for the caller.
    fn watched(&self, id: &opcua::types::NodeId) -> Option<(NodePath, Watched, String)> {
        if let Some(variable) = self.io_variable(id) {
            let path = variable.path();
            return Some(match variable {
                super::io::IoVariable::Segment {
                    node,
                    segment,
                    field,
                } => (node, Watched::Led { segment, field }, path),
                super::io::IoVariable::Channel { node, channel } => {
                    (node, Watched::Channel(channel), path)
                }
            });
        }
        match self.target(id)? {
            Target::Object { node, index, sub } => {
                let path = node.object(index, sub);
                Some((node, Watched::Entry((index, sub)), path))
            }
            _ => None,
        }
    }

    /// A monitored item on a variable read from the node's dictionary
    /// (dictionary, I/O and LED variables), handed to its node's sampler:
    /// true when `item` is one (its status set), false for any other.
    fn monitor_sampled(
        &self,
        context: &RequestContext,
        address_space: &RwLock<AddressSpace>,
        item: &mut CreateMonitoredItem,
    ) -> bool {
        if item.item_to_monitor().attribute_id != AttributeId::Value {
            return false;
        }
        let Some((node, watched, path)) = self.watched(&item.item_to_monitor().node_id) else {
            return false;
        };
        let readable = {
            let space = address_space.read();
            space
                .validate_node_read(context, item.item_to_monitor())
                .map(|_| ())
        };
        if let Err(status) = readable {
            item.set_status(status);
            return true;
        }
        let caller = self.caller(context, "Read", &path, None);
        let initial = self.door.sampling.monitor(
            item.handle(),
            node,
            watched,
            item.sampling_interval(),
            caller,
        );
        if let Some(value) = initial {
            item.set_initial_value(value);
        }
        item.set_status(StatusCode::Good);
        true
    }

    /// A dictionary entry written over SDO: checked by the EDS (type,
    /// range) as a REST write is, then one write operation.
    async fn write_object(
        &self,
        context: &RequestContext,
        node: &NodePath,
        index: u16,
        sub: u8,
        value: &Variant,
    ) -> Result<(), GatewayError> {
        let json = super::values::json_of(value).ok_or_else(|| {
            GatewayError::InvalidValue(format!(
                "{}: a {:?} is no value of a dictionary entry",
                crate::gateway::object_item(index, sub),
                value.type_id()
            ))
        })?;
        let caller = self.caller(
            context,
            "Write",
            &node.object(index, sub),
            Some(json.to_string()),
        );
        let handle = handle(&self.door.gateway, node)?;
        let entry = entry(&handle, index, sub)?;
        let typed = entry.value_from_json(&json, Some(handle.info().id))?;
        handle
            .write_object(&caller, index, sub, typed.to_bytes())
            .await
    }
}

/// The tree's own check of a write: the variable's access level for the
/// session's user and the value's type.
fn tree_allows(
    context: &RequestContext,
    address_space: &RwLock<AddressSpace>,
    write: &WriteNode,
) -> Result<(), StatusCode> {
    let mut space = address_space.write();
    let type_tree = context.type_tree.read();
    space
        .validate_node_write(context, write.value(), &*type_tree)
        .map(|_| ())
}

fn handle(gateway: &Gateway, node: &NodePath) -> Result<crate::gateway::NodeHandle, GatewayError> {
    gateway.node_handle(&node.bus, &node.node.to_string())
}

/// The EDS's description of an entry (the tree has a variable only for
/// what the EDS describes).
pub(super) fn entry(
    handle: &crate::gateway::NodeHandle,
    index: u16,
    sub: u8,
) -> Result<crate::canopen::od::SubObject, GatewayError> {
    handle
        .info()
        .eds_entry
        .as_ref()
        .and_then(|entry| entry.eds.dictionary.sub(index, sub).cloned())
        .ok_or_else(|| {
            GatewayError::UnknownSubObject(format!(
                "the node's EDS describes no {}",
                crate::gateway::object_item(index, sub)
            ))
        })
}

/// A motion's failure as its error (the stop's attempts are in the audit
/// row).
fn failed(failed: MotionFailed) -> GatewayError {
    failed.error
}

fn period_ms(period: std::time::Duration) -> u32 {
    u32::try_from(period.as_millis()).unwrap_or(u32::MAX)
}

fn argument<'a>(args: &'a [Variant], at: usize, name: &str) -> Result<&'a Variant, GatewayError> {
    args.get(at)
        .ok_or_else(|| GatewayError::InvalidRequest(format!("argument {name} is missing")))
}

fn string_arg(args: &[Variant], at: usize, name: &str) -> Result<String, GatewayError> {
    match argument(args, at, name)? {
        Variant::String(text) => Ok(text.as_ref().to_string()),
        other => Err(GatewayError::InvalidValue(format!(
            "argument {name} is a String, not {:?}",
            other.type_id()
        ))),
    }
}

fn double_arg(args: &[Variant], at: usize, name: &str) -> Result<f64, GatewayError> {
    Ok(match argument(args, at, name)? {
        Variant::Double(value) => *value,
        Variant::Float(value) => f64::from(*value),
        Variant::SByte(value) => f64::from(*value),
        Variant::Byte(value) => f64::from(*value),
        Variant::Int16(value) => f64::from(*value),
        Variant::UInt16(value) => f64::from(*value),
        Variant::Int32(value) => f64::from(*value),
        Variant::UInt32(value) => f64::from(*value),
        other => {
            return Err(GatewayError::InvalidValue(format!(
                "argument {name} is a Double, not {:?}",
                other.type_id()
            )));
        }
    })
}

fn uint_arg(args: &[Variant], at: usize, name: &str) -> Result<u32, GatewayError> {
    match argument(args, at, name)? {
        Variant::UInt32(value) => Ok(*value),
        other => Err(GatewayError::InvalidValue(format!(
            "argument {name} is a UInt32, not {:?}",
            other.type_id()
        ))),
    }
}

fn bool_arg(args: &[Variant], at: usize, name: &str) -> Result<bool, GatewayError> {
    match argument(args, at, name)? {
        Variant::Boolean(value) => Ok(*value),
        other => Err(GatewayError::InvalidValue(format!(
            "argument {name} is a Boolean, not {:?}",
            other.type_id()
        ))),
    }
}

#[async_trait]
impl InMemoryNodeManagerImpl for CandeckNodes {
    async fn init(&self, address_space: &mut AddressSpace, _context: ServerContext) {
        let buses: Vec<String> = self
            .door
            .gateway
            .buses_in_order()
            .iter()
            .map(|bus| bus.name().to_string())
            .collect();
        super::tree::build_fixed(address_space, self.ns, &buses);
    }

    fn name(&self) -> &str {
        "candeck"
    }

    fn namespaces(&self) -> Vec<NamespaceMetadata> {
        vec![NamespaceMetadata {
            namespace_uri: browse::NAMESPACE.to_string(),
            namespace_index: self.ns,
            ..Default::default()
        }]
    }

    async fn read_values(
        &self,
        context: &RequestContext,
        address_space: &RwLock<AddressSpace>,
        nodes: &[&ParsedReadValueId],
        max_age: f64,
        timestamps_to_return: TimestampsToReturn,
    ) -> Vec<DataValue> {
        let mut values = Vec::with_capacity(nodes.len());
        let mut io_reads = super::io::Reads::default();
        for node in nodes {
            if let Some(variable) = self.io_variable(&node.node_id) {
                let readable = {
                    let space = address_space.read();
                    space.validate_node_read(context, node).map(|_| ())
                };
                values.push(match readable {
                    Ok(()) => {
                        let caller = self.caller(context, "Read", &variable.path(), None);
                        io_reads.read(&self.door.gateway, &caller, &variable).await
                    }
                    Err(status) => DataValue {
                        status: Some(status),
                        ..Default::default()
                    },
                });
                continue;
            }
            if let Some(Target::Object {
                node: path,
                index,
                sub,
            }) = self.target(&node.node_id)
            {
                // Only what the tree has (and the client may read).
                let readable = {
                    let space = address_space.read();
                    space.validate_node_read(context, node).map(|_| ())
                };
                match readable {
                    Ok(()) => values.push(self.read_object(context, &path, index, sub).await),
                    Err(status) => values.push(DataValue {
                        status: Some(status),
                        ..Default::default()
                    }),
                }
                continue;
            }
            // An axis value read: its feed runs a while, and this read
            // waits for its first sample.
            if let Some(axis) = self.door.demand.axis_of(&node.node_id) {
                self.door.demand.read(&axis).await;
            }
            let space = address_space.read();
            values.push(space.read(context, node, max_age, timestamps_to_return));
        }
        values
    }

    async fn create_value_monitored_items(
        &self,
        context: &RequestContext,
        address_space: &RwLock<AddressSpace>,
        items: &mut [&mut &mut CreateMonitoredItem],
    ) {
        for item in items.iter() {
            if let Some(axis) = self.door.demand.axis_of(&item.item_to_monitor().node_id) {
                self.door.demand.monitor(axis, item.handle());
            }
        }
        // Dictionary, I/O and LED variables are sampled (super::sampling),
        // not read here: their first value is the sampler's.
        let mut items: Vec<&mut &mut CreateMonitoredItem> = {
            let mut others = Vec::with_capacity(items.len());
            for item in items.iter_mut() {
                if !self.monitor_sampled(context, address_space, item) {
                    others.push(&mut **item);
                }
            }
            others
        };
        let items = items.as_mut_slice();
        let to_read: Vec<_> = items.iter().map(|item| item.item_to_monitor()).collect();
        let values = self
            .read_values(
                context,
                address_space,
                &to_read,
                0.0,
                TimestampsToReturn::Both,
            )
            .await;
        for (value, item) in values.into_iter().zip(items.iter_mut()) {
            if value.status() != StatusCode::BadAttributeIdInvalid {
                item.set_initial_value(value);
            }
            item.set_status(StatusCode::Good);
        }
    }

    async fn modify_monitored_items(
        &self,
        _context: &RequestContext,
        items: &[&MonitoredItemUpdateRef],
    ) {
        for item in items {
            if item.attribute() == AttributeId::Value {
                self.door
                    .sampling
                    .modify(item.handle(), item.update().revised_sampling_interval);
            }
        }
    }

    async fn delete_monitored_items(&self, _context: &RequestContext, items: &[&MonitoredItemRef]) {
        for item in items {
            self.door.demand.unmonitor(item.handle());
            self.door.sampling.unmonitor(item.handle());
        }
    }

    async fn write(
        &self,
        context: &RequestContext,
        address_space: &RwLock<AddressSpace>,
        nodes_to_write: &mut [&mut WriteNode],
    ) -> Result<(), StatusCode> {
        for write in nodes_to_write.iter_mut() {
            if let Some(variable) = self.io_variable(&write.value().node_id) {
                self.write_io(context, address_space, write, &variable)
                    .await;
                continue;
            }
            let target = self.target(&write.value().node_id);
            let Some(Target::Object { node, index, sub }) = target else {
                write.set_status(StatusCode::BadNotWritable);
                continue;
            };
            if write.value().attribute_id != AttributeId::Value {
                write.set_status(StatusCode::BadNotWritable);
                continue;
            }
            if let Err(status) = tree_allows(context, address_space, write) {
                write.set_status(status);
                continue;
            }
            let Some(value) = write.value().value.value.clone() else {
                write.set_status(StatusCode::BadNothingToDo);
                continue;
            };
            match self.write_object(context, &node, index, sub, &value).await {
                Ok(()) => write.set_status(StatusCode::Good),
                Err(error) => {
                    write.set_status(status_of(&error));
                    write.set_diagnostic_info(diagnostic_of(&error));
                }
            }
        }
        Ok(())
    }

    async fn call(
        &self,
        context: &RequestContext,
        _address_space: &RwLock<AddressSpace>,
        methods_to_call: &mut [&mut &mut MethodCall],
    ) -> Result<(), StatusCode> {
        for call in methods_to_call.iter_mut() {
            let method_id = call.method_id().clone();
            let Some(target) = self.target(&method_id) else {
                call.set_status(StatusCode::BadMethodInvalid);
                continue;
            };
            let name = method_id.identifier.to_string();
            let args = call.arguments().to_vec();
            match self.call_one(context, target, &name, &args).await {
                Ok(outputs) => {
                    call.set_outputs(outputs);
                    call.set_status(StatusCode::Good);
                }
                Err(error) => {
                    tracing::info!("opcua: {name}: {error}");
                    call.set_status(status_of(&error));
                    call.set_diagnostic_info(diagnostic_of(&error));
                }
            }
        }
        Ok(())
    }
}
