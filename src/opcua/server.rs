//! The OPC UA server at work: async-opcua's server with candeck's node
//! manager and users, its PKI, endpoints and limits, started beside the
//! other doors by `candeck serve` and stopped with them.

use std::path::Path;
use std::sync::{Arc, OnceLock};

use opcua::crypto::SecurityPolicy;
use opcua::server::node_manager::memory::{InMemoryNodeManager, InMemoryNodeManagerBuilder};
use opcua::server::{ServerBuilder, ServerEndpoint, ServerHandle};
use opcua::types::{BuildInfo, DateTime, MessageSecurityMode};

use super::browse::NAMESPACE;
use super::config::OpcUaConfig;
use super::feed::{AxisDemand, Sink};
use super::leases::SessionLeases;
use super::revisions::Revisions;
use super::sampling::Sampling;
use super::space::{CandeckNodes, Door};
use super::users::TokenUsers;
use crate::gateway::Gateway;

/// The endpoints: every policy async-opcua has that is not deprecated,
/// signed and encrypted, then signed only; `None` where the config says
/// (loopback).
fn endpoints(unsecured: bool) -> Vec<(String, ServerEndpoint)> {
    let mut endpoints = Vec::new();
    for policy in [
        SecurityPolicy::Basic256Sha256,
        SecurityPolicy::Aes128Sha256RsaOaep,
        SecurityPolicy::Aes256Sha256RsaPss,
    ] {
        for mode in [
            MessageSecurityMode::SignAndEncrypt,
            MessageSecurityMode::Sign,
        ] {
            endpoints.push((
                format!("{policy}_{mode}").to_lowercase(),
                ServerEndpoint::new("/", policy, mode, &[]),
            ));
        }
    }
    if unsecured {
        let mut none = ServerEndpoint::new_none("/", &[]);
        // A password over it is encrypted with the server's key all the same.
        none.password_security_policy = Some(SecurityPolicy::Basic256Sha256.to_string());
        endpoints.push(("none".to_string(), none));
    }
    endpoints
}

/// The machine's name, for the endpoint URLs and the application URI of a
/// server that listens on every address.
fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .or_else(|| std::env::var("HOSTNAME").ok())
        .map(|name| name.trim().to_string())
        .filter(|name| !name.is_empty())
        .unwrap_or_else(|| "localhost".to_string())
}

/// The PKI folders, private to the gateway's user (0700): the key is in
/// `private/`, and whoever may write `trusted/` decides who connects.
fn private_folders(pki: &Path) -> std::io::Result<()> {
    use std::os::unix::fs::{DirBuilderExt, PermissionsExt};
    for folder in ["", "own", "private", "trusted", "rejected"] {
        let path = pki.join(folder);
        std::fs::DirBuilder::new()
            .recursive(true)
            .mode(0o700)
            .create(&path)?;
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o700))?;
    }
    Ok(())
}

/// The OPC UA server of `candeck serve`.
pub struct OpcUaServer {
    handle: ServerHandle,
    local: std::net::SocketAddr,
    server: tokio::task::JoinHandle<Result<(), String>>,
    helpers: Vec<tokio::task::JoinHandle<()>>,
}

impl OpcUaServer {
    /// Listens on `config.listen` and serves the gateway's machine.
    pub async fn start(gateway: Gateway, config: &OpcUaConfig) -> Result<Self, String> {
        private_folders(&config.pki_dir)
            .map_err(|err| format!("opcua_pki_dir {}: {err}", config.pki_dir.display()))?;
        let listener = tokio::net::TcpListener::bind(config.listen)
            .await
            .map_err(|err| format!("cannot listen on {}: {err}", config.listen))?;
        let local = listener
            .local_addr()
            .map_err(|err| format!("cannot listen on {}: {err}", config.listen))?;
        let host = if local.ip().is_unspecified() {
            host_name()
        } else {
            local.ip().to_string()
        };
        let users = TokenUsers::new(gateway.tokens().clone(), config.logins);
        let leases = Arc::new(SessionLeases::new(gateway.lease_period()));
        let door_cell: Arc<OnceLock<Arc<Door>>> = Arc::default();
        let node_manager = {
            let (gateway, leases, door_cell) = (gateway.clone(), leases.clone(), door_cell.clone());
            InMemoryNodeManagerBuilder::new(
                move |context: opcua::server::node_manager::ServerContext,
                      space: &mut opcua::server::address_space::AddressSpace| {
                    let ns = context
                        .type_tree
                        .write()
                        .namespaces_mut()
                        .add_namespace(NAMESPACE);
                    super::events::register_fields(&mut context.type_tree.write(), ns);
                    space.add_namespace(NAMESPACE, ns);
                    let door = Arc::new(Door {
                        gateway,
                        users,
                        leases,
                        demand: Arc::new(AxisDemand::new(ns)),
                        sampling: Arc::new(Sampling::new()),
                    });
                    let _ = door_cell.set(door.clone());
                    CandeckNodes::new(door, ns)
                },
            )
        };
        let limits = config.limits;
        let mut builder = ServerBuilder::new()
            .application_name("candeck")
            .application_uri(format!("urn:candeck:{host}"))
            .product_uri("urn:candeck")
            .build_info(BuildInfo {
                product_uri: "urn:candeck".into(),
                manufacturer_name: "candeck".into(),
                product_name: "candeck CANopen gateway".into(),
                software_version: env!("CARGO_PKG_VERSION").into(),
                build_number: env!("CARGO_PKG_VERSION").into(),
                build_date: DateTime::now(),
            })
            .pki_dir(&config.pki_dir)
            .certificate_path("own/cert.der")
            .private_key_path("private/private.pem")
            // The application certificate is made on the first start.
            .create_sample_keypair(true)
            .trust_client_certs(false)
            .host(host)
            .port(local.port())
            .discovery_urls(vec!["/".to_string()])
            .max_sessions(limits.max_sessions)
            .max_message_size(limits.max_message_size)
            .max_session_timeout_ms(limits.session_timeout.as_millis() as u64)
            .with_authenticator(Arc::new(TokenUsers::new(
                gateway.tokens().clone(),
                config.logins,
            )))
            .with_node_manager(node_manager);
        for (id, endpoint) in endpoints(config.logins.unsecured_endpoint) {
            builder = builder.add_endpoint(id, endpoint);
        }
        let subscription_limits = &mut builder.limits_mut().subscriptions;
        subscription_limits.max_subscriptions_per_session = limits.max_subscriptions;
        subscription_limits.max_monitored_items_per_sub = limits.max_monitored_items;
        let (server, handle) = builder.build()?;
        let door = door_cell
            .get()
            .cloned()
            .ok_or("the OPC UA node manager was not built")?;
        let manager = handle
            .node_managers()
            .get_of_type::<InMemoryNodeManager<CandeckNodes>>()
            .ok_or("the OPC UA node manager is missing")?;
        let ns = handle
            .get_namespace_index(NAMESPACE)
            .ok_or("the candeck namespace is missing")?;
        door.sampling
            .start(gateway.clone(), handle.subscriptions().clone(), ns);
        let sink = Sink::new(ns, manager, handle.subscriptions().clone());
        let events = super::events::EventSink::new(ns, handle.subscriptions().clone());
        let revisions = Arc::new(Revisions::default());
        let mut helpers = revisions.spawn(&gateway);
        helpers.extend([
            tokio::spawn(super::events::run(gateway.clone(), events)),
            tokio::spawn(super::feed::run(
                gateway.clone(),
                sink,
                door.demand.clone(),
                revisions,
            )),
            tokio::spawn(
                leases
                    .clone()
                    .run(gateway.clone(), gateway.lease_period() / 3),
            ),
        ]);
        let server = tokio::spawn(server.run_with(listener));
        Ok(Self {
            handle,
            local,
            server,
            helpers,
        })
    }

    /// Where it listens (the port, when 0 was asked).
    pub fn local_addr(&self) -> std::net::SocketAddr {
        self.local
    }

    /// Closes the sessions and stops listening, waiting at most `grace`.
    pub async fn stop(mut self, grace: std::time::Duration) {
        self.handle.cancel();
        if tokio::time::timeout(grace, &mut self.server).await.is_err() {
            tracing::warn!("opcua: the server did not stop within {grace:?}: ended");
            self.server.abort();
        }
        for helper in &self.helpers {
            helper.abort();
        }
    }
}
