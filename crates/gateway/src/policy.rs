//! What the gateway asks of a [`Caller`] before it acts, whichever door the
//! caller came through: its role ([`Gateway::require_role`]) and a write
//! from its write rate limit ([`Gateway::take_write`]). A door may refuse
//! earlier (REST's route table), but the gateway's operations never rely on
//! it.
//!
//! The bucket a write is drawn from:
//! - a caller of a gateway with tokens: its token's name, whichever door
//!   it uses (a token's REST, CiA 309-5 and CiA 309-3 writes share one
//!   bucket); a gateway without tokens has no names to count by, and does
//!   not limit these;
//! - the Sparkplug edge node, always: MQTT carries no sender identity, so
//!   every MQTT client of the edge node shares its configured identity's
//!   bucket; except that a command presenting the motion lease held on
//!   its axis ([`Gateway::take_write_presenting`]) draws from a bucket of
//!   that lease: the lease id is the capability, so a flood of commands
//!   that present none (or a wrong one) from another MQTT client cannot
//!   starve the lease's holder. An id that is no lease held on the axis
//!   gets no bucket of its own: ids made up by the dozen would otherwise
//!   each bring a fresh bucket.

use super::GatewayError;
use super::access::Role;
use super::caller::{Caller, Channel};
use super::motion_lease::AxisKey;
use super::service::Gateway;

/// Every kind of operation a caller can ask of the gateway, by what the
/// gateway asks of the caller for it: the one table of roles
/// ([`Operation::required_role`]) and of what draws on the write rate
/// ([`Operation::draws_on_write_rate`]). The operations check it
/// themselves ([`Gateway::require`]); a door that refuses earlier (REST's
/// guard, before it reads a body) looks its request up here too, so that
/// no door has a role table of its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Operation {
    /// Any read of the machine: buses, nodes, objects, axes, values, I/O,
    /// PDOs, SYNC, frames, recordings, virtual devices, loggers, the
    /// history, EDS files, metrics, the stream.
    View,
    /// STOP ALL: whoever watches a machine may stop it, as anyone may
    /// press an emergency stop; it can only stop motion. Never limited.
    StopAll,
    /// A scan: it reads identities only, but adds nodes and marks silent
    /// ones offline.
    Scan,
    /// An NMT command to a node or to the whole bus.
    Nmt,
    /// A node's boot-up run again by the network manager (configuration
    /// download and NMT start).
    BootNode,
    /// An object write (SDO download).
    WriteObject,
    /// LED segments and scenes.
    SetLeds,
    /// A drive axis's state, fault reset, halt, moves and step tests.
    Motion,
    /// Renewing the motion lease of a move the caller started.
    RenewLease,
    /// The outputs of an I/O module.
    SetOutputs,
    /// Process data sent straight to a device's mapped objects (an RPDO).
    SendRpdo,
    /// The bus's SYNC period.
    SetSync,
    /// A raw CAN frame.
    SendFrame,
    /// A node-ID change of one node, as its operator's NMT reset is.
    ChangeNodeId,
    /// Data loggers started and deleted: sampling takes the nodes' SDO
    /// queues, as an operator's reads would.
    Logger,
    /// An EDS file assigned to a node by hand, or unassigned.
    AssignEds,
    /// Parameters stored to, or restored from, a node's non-volatile
    /// memory (0x1010, 0x1011).
    StoreRestore,
    /// A node's configuration restored from a DCF.
    RestoreConfiguration,
    /// A program downloaded to a node (CiA 302-3).
    DownloadProgram,
    /// A PDO's communication and mapping parameters.
    ConfigurePdo,
    /// A bus recorded to a log file, started or stopped.
    Record,
    /// LSS: Fastscan and node-ID assignment reconfigure the bus's nodes.
    Lss,
    /// Virtual devices added, removed, and their faults.
    VirtualDevices,
    /// EDS files uploaded to, or deleted from, the catalog.
    ManageEds,
    /// Alarms acknowledged, one or all that match: an operator's word
    /// that they saw them. It changes no device: it takes no write.
    AcknowledgeAlarm,
    /// A bus's machine recovered as a whole: every faulted axis reset,
    /// every axis last enabled enabled again. Each axis's own operation
    /// takes its write, so the whole takes none of its own.
    RecoverMachine,
    /// An object write that switches off a device's protection against
    /// the gateway's death (docs/security.md, "Watchdog policy"), on top
    /// of the [`Self::WriteObject`] or [`Self::RestoreConfiguration`] it
    /// rides on, which took the write.
    SwitchWatchdogOff,
}

impl Operation {
    /// The least role that may ask for it.
    pub fn required_role(self) -> Role {
        match self {
            Self::View | Self::StopAll => Role::Viewer,
            Self::Scan
            | Self::Nmt
            | Self::BootNode
            | Self::WriteObject
            | Self::SetLeds
            | Self::Motion
            | Self::RenewLease
            | Self::SetOutputs
            | Self::SendRpdo
            | Self::SetSync
            | Self::SendFrame
            | Self::ChangeNodeId
            | Self::Logger
            | Self::AssignEds
            | Self::AcknowledgeAlarm
            | Self::RecoverMachine => Role::Operator,
            Self::StoreRestore
            | Self::RestoreConfiguration
            | Self::DownloadProgram
            | Self::ConfigurePdo
            | Self::Record
            | Self::Lss
            | Self::VirtualDevices
            | Self::ManageEds
            | Self::SwitchWatchdogOff => Role::Admin,
        }
    }

    /// Whether it takes a write from its caller's write rate limit: what
    /// changes the machine, except what keeps it safe: a stop (STOP ALL
    /// here; a halt or a walk out of operation enabled is a [`Self::Motion`]
    /// the motion facade never limits) and a lease renewal (refused, it
    /// would stop the axis its holder is moving).
    pub fn draws_on_write_rate(self) -> bool {
        !matches!(
            self,
            Self::View
                | Self::StopAll
                | Self::RenewLease
                | Self::AcknowledgeAlarm
                | Self::RecoverMachine
                | Self::SwitchWatchdogOff
        )
    }
}

impl Gateway {
    /// Refuses `caller` an operation of `kind` its role does not allow
    /// ([`Gateway::require_role`] with [`Operation::required_role`]).
    pub fn require(&self, caller: &Caller, kind: Operation) -> Result<(), GatewayError> {
        self.require_role(caller, kind.required_role())
    }

    /// What an operation of `kind` asks of `caller` before it acts: its
    /// role, then one write of its rate where the kind draws on it.
    pub fn admit(&self, caller: &Caller, kind: Operation) -> Result<(), GatewayError> {
        self.require(caller, kind)?;
        if kind.draws_on_write_rate() {
            self.take_write(caller)?;
        }
        Ok(())
    }

    /// Refuses `caller` what needs `needed`: a caller with a role is held
    /// to it (the edge node's configured role, on an open gateway too); one
    /// without is refused when the gateway has tokens (`unauthenticated`),
    /// and allowed on an open gateway (no tokens: no roles).
    pub fn require_role(&self, caller: &Caller, needed: Role) -> Result<(), GatewayError> {
        match caller.role {
            Some(role) if role >= needed => Ok(()),
            Some(role) => Err(GatewayError::Forbidden(format!(
                "{} has the role {role} over {}; this needs {needed}",
                caller.who, caller.channel
            ))),
            None if self.tokens.required() => Err(GatewayError::Unauthenticated(format!(
                "this gateway asks for a token: {} has none over {}",
                caller.who, caller.channel
            ))),
            None => Ok(()),
        }
    }

    /// Takes one write of `caller` from the write rate limit (see the
    /// module docs for its bucket); `rate_limited` when it is over its
    /// rate.
    pub fn take_write(&self, caller: &Caller) -> Result<(), GatewayError> {
        if !self.counts_writes_of(caller) {
            return Ok(());
        }
        self.writes.take_or_refuse(&caller.who)
    }

    /// [`Gateway::take_write`] for a motion command on `axis` that presents
    /// `lease` (Sparkplug's `Axis {n}/Lease Id`): from the bucket of that
    /// lease when it is the one held on the axis, else from the caller's.
    pub fn take_write_presenting(
        &self,
        caller: &Caller,
        axis: &AxisKey,
        lease: Option<&str>,
    ) -> Result<(), GatewayError> {
        if !self.counts_writes_of(caller) {
            return Ok(());
        }
        match lease.filter(|id| self.leases.holds(axis, id)) {
            // A token name has no ':' (`Token::new`), an MQTT identity no
            // `lease:` prefix: this bucket is no caller's.
            Some(id) => self.writes.take_or_refuse(&format!("lease:{id}")),
            None => self.writes.take_or_refuse(&caller.who),
        }
    }

    fn counts_writes_of(&self, caller: &Caller) -> bool {
        self.tokens.required() || caller.channel == Channel::Sparkplug
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::access::{RateLimit, Token, Tokens};

    fn gateway(tokens: bool) -> Gateway {
        let tokens = if tokens {
            Tokens::new(vec![
                Token::new("hmi", Role::Viewer, "v1ewer-0123456789abcdef").unwrap(),
            ])
        } else {
            Tokens::default()
        };
        Gateway::new([])
            .with_tokens(tokens)
            .with_write_limit(Some(RateLimit {
                per_second: 0.001,
                burst: 2,
            }))
    }

    #[tokio::test(start_paused = true)]
    async fn roles_are_required_of_callers_that_have_one_and_of_all_with_tokens() {
        let open = gateway(false);
        let anonymous = Caller::new(Channel::Rest, "anonymous", None);
        assert!(open.require_role(&anonymous, Role::Admin).is_ok());
        let viewer = Caller::new(Channel::Sparkplug, "mqtt:scada", Some(Role::Viewer));
        let refused = open.require_role(&viewer, Role::Operator).unwrap_err();
        assert_eq!(refused.code(), "forbidden", "{refused}");
        assert!(open.require_role(&viewer, Role::Viewer).is_ok());

        let closed = gateway(true);
        let refused = closed.require_role(&anonymous, Role::Viewer).unwrap_err();
        assert_eq!(refused.code(), "unauthenticated", "{refused}");
        let hmi = Caller::new(Channel::Cia309_3, "hmi", Some(Role::Viewer));
        assert!(closed.require_role(&hmi, Role::Viewer).is_ok());
        let refused = closed.require_role(&hmi, Role::Operator).unwrap_err();
        assert_eq!(refused.code(), "forbidden", "{refused}");
    }

    #[tokio::test(start_paused = true)]
    async fn writes_are_counted_by_token_name_and_the_edge_node_always() {
        let open = gateway(false);
        let anonymous = Caller::new(Channel::Rest, "anonymous", None);
        for _ in 0..5 {
            assert!(open.take_write(&anonymous).is_ok());
        }
        let mqtt = Caller::new(Channel::Sparkplug, "mqtt:scada", Some(Role::Operator));
        assert!(open.take_write(&mqtt).is_ok());
        assert!(open.take_write(&mqtt).is_ok());
        assert_eq!(open.take_write(&mqtt).unwrap_err().code(), "rate_limited");

        // One bucket per token name, whichever door.
        let closed = gateway(true);
        let rest = Caller::new(Channel::Rest, "hmi", Some(Role::Viewer));
        let ascii = Caller::new(Channel::Cia309_3, "hmi", Some(Role::Viewer));
        assert!(closed.take_write(&rest).is_ok());
        assert!(closed.take_write(&ascii).is_ok());
        assert_eq!(closed.take_write(&rest).unwrap_err().code(), "rate_limited");
    }

    #[tokio::test(start_paused = true)]
    async fn an_id_that_is_no_lease_held_on_the_axis_draws_from_the_callers_bucket() {
        let open = gateway(false);
        let mqtt = Caller::new(Channel::Sparkplug, "mqtt:scada", Some(Role::Operator));
        let axis = AxisKey {
            bus: "demo".into(),
            node: 1,
            axis: 1,
        };
        // Made-up ids bring no bucket of their own.
        for n in 0..2 {
            let made_up = format!("made-up-lease-id-{n:04}");
            assert!(
                open.take_write_presenting(&mqtt, &axis, Some(&made_up))
                    .is_ok()
            );
        }
        let refused = open
            .take_write_presenting(&mqtt, &axis, Some("made-up-lease-id-0002"))
            .unwrap_err();
        assert_eq!(refused.code(), "rate_limited");
    }
}
