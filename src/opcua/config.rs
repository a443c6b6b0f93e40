//! The OPC UA server's settings (config keys `opcua_*`, `--opcua-listen`;
//! docs/configuration.md, docs/opcua.md) and who may log in where: the
//! rules are REST's (docs/security.md), so that the same machine is not
//! open through one door and closed through another.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

/// The default `opcua_max_sessions`.
pub const DEFAULT_MAX_SESSIONS: usize = 20;
/// The default `opcua_max_subscriptions` (per session).
pub const DEFAULT_MAX_SUBSCRIPTIONS: usize = 10;
/// The default `opcua_max_monitored_items` (per subscription).
pub const DEFAULT_MAX_MONITORED_ITEMS: usize = 1000;
/// The default `opcua_max_message_size`, in bytes.
pub const DEFAULT_MAX_MESSAGE_SIZE: usize = 4 * 1024 * 1024;
/// The default `opcua_session_timeout_ms`: a session no request kept
/// alive for this long is closed, and the motion leases it holds lapse.
pub const DEFAULT_SESSION_TIMEOUT: Duration = Duration::from_secs(60);

/// The bounds of the server, each a config key.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OpcUaLimits {
    pub max_sessions: usize,
    pub max_subscriptions: usize,
    pub max_monitored_items: usize,
    pub max_message_size: usize,
    /// The longest session timeout a client may ask for: an idle session
    /// is closed after it.
    pub session_timeout: Duration,
}

impl Default for OpcUaLimits {
    fn default() -> Self {
        Self {
            max_sessions: DEFAULT_MAX_SESSIONS,
            max_subscriptions: DEFAULT_MAX_SUBSCRIPTIONS,
            max_monitored_items: DEFAULT_MAX_MONITORED_ITEMS,
            max_message_size: DEFAULT_MAX_MESSAGE_SIZE,
            session_timeout: DEFAULT_SESSION_TIMEOUT,
        }
    }
}

/// Who may open a session, from where the server listens and whether the
/// gateway has tokens.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Logins {
    /// Username (a token's name) and password (its secret): whenever the
    /// gateway has tokens.
    pub users: bool,
    /// Anonymous: only without tokens, and on loopback unless
    /// `--insecure`, as REST answers an anonymous request only then.
    pub anonymous: bool,
    /// The endpoint without security (`None`): only on loopback, where the
    /// messages never leave the machine.
    pub unsecured_endpoint: bool,
}

/// The OPC UA server's settings; `None` in the serve settings: off.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OpcUaConfig {
    pub listen: SocketAddr,
    /// The application certificate and key (`own/`, `private/`), the
    /// client certificates trusted (`trusted/`) and those refused until
    /// an administrator moves them to `trusted/` (`rejected/`).
    pub pki_dir: PathBuf,
    pub limits: OpcUaLimits,
    pub logins: Logins,
}

/// The PKI directory without `opcua_pki_dir`: `DATA_DIR/opcua-pki`, else
/// `opcua-pki` in the working directory (the certificate must outlive a
/// restart, or every client would have to trust a new one).
pub fn default_pki_dir(data_dir: Option<&std::path::Path>) -> PathBuf {
    data_dir.map_or_else(|| PathBuf::from("opcua-pki"), |dir| dir.join("opcua-pki"))
}

impl OpcUaConfig {
    /// The settings for `listen`, checked against REST's rule: an address
    /// other than loopback needs tokens (no anonymous login reaches it) or
    /// `--insecure` (`insecure`: a container's port published on the
    /// host's loopback, say); there anonymous sessions are still only
    /// served over signed and encrypted channels, to clients whose
    /// certificate an administrator trusted: the `None` endpoint is
    /// loopback's alone.
    pub fn new(
        listen: SocketAddr,
        pki_dir: PathBuf,
        limits: OpcUaLimits,
        tokens_required: bool,
        insecure: bool,
    ) -> Result<Self, String> {
        let loopback = listen.ip().is_loopback();
        if !loopback && !tokens_required && !insecure {
            return Err(format!(
                "refusing opcua_listen {listen} without tokens: anonymous OPC UA sessions are only \
                 served on loopback; configure tokens (config file [[tokens]] or CANDECK_TOKENS: \
                 the token's name is the user name, its secret the password), listen on 127.0.0.1, \
                 or pass --insecure"
            ));
        }
        for (key, value) in [
            ("opcua_max_sessions", limits.max_sessions),
            ("opcua_max_subscriptions", limits.max_subscriptions),
            ("opcua_max_monitored_items", limits.max_monitored_items),
        ] {
            if value == 0 {
                return Err(format!("{key} must be at least 1"));
            }
        }
        if limits.max_message_size < 8192 {
            return Err(format!(
                "opcua_max_message_size {} is below OPC UA's smallest buffer, 8192 bytes",
                limits.max_message_size
            ));
        }
        if limits.session_timeout < Duration::from_secs(1) {
            return Err("opcua_session_timeout_ms must be at least 1000".to_string());
        }
        Ok(Self {
            listen,
            pki_dir,
            limits,
            logins: Logins {
                users: tokens_required,
                anonymous: (loopback || insecure) && !tokens_required,
                unsecured_endpoint: loopback,
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(listen: &str, tokens: bool) -> Result<OpcUaConfig, String> {
        OpcUaConfig::new(
            listen.parse().unwrap(),
            PathBuf::from("pki"),
            OpcUaLimits::default(),
            tokens,
            false,
        )
    }

    #[test]
    fn anonymous_and_the_unsecured_endpoint_are_for_loopback_only() {
        let open_loopback = config("127.0.0.1:4840", false).unwrap().logins;
        assert_eq!(
            open_loopback,
            Logins {
                users: false,
                anonymous: true,
                unsecured_endpoint: true
            }
        );
        let tokens_loopback = config("[::1]:4840", true).unwrap().logins;
        assert_eq!(
            tokens_loopback,
            Logins {
                users: true,
                anonymous: false,
                unsecured_endpoint: true
            }
        );
        let tokens_network = config("0.0.0.0:4840", true).unwrap().logins;
        assert_eq!(
            tokens_network,
            Logins {
                users: true,
                anonymous: false,
                unsecured_endpoint: false
            }
        );
        let refused = config("0.0.0.0:4840", false).unwrap_err();
        assert!(refused.contains("without tokens"), "{refused}");
    }

    #[test]
    fn insecure_opens_anonymous_sessions_beyond_loopback_but_never_the_none_endpoint() {
        let insecure = |listen: &str, tokens| {
            OpcUaConfig::new(
                listen.parse().unwrap(),
                PathBuf::from("pki"),
                OpcUaLimits::default(),
                tokens,
                true,
            )
            .unwrap()
            .logins
        };
        assert_eq!(
            insecure("0.0.0.0:4840", false),
            Logins {
                users: false,
                anonymous: true,
                unsecured_endpoint: false
            }
        );
        // Tokens win over --insecure, as for REST.
        assert_eq!(
            insecure("0.0.0.0:4840", true),
            Logins {
                users: true,
                anonymous: false,
                unsecured_endpoint: false
            }
        );
    }

    #[test]
    fn limits_are_checked() {
        let limits = |change: fn(&mut OpcUaLimits)| {
            let mut limits = OpcUaLimits::default();
            change(&mut limits);
            OpcUaConfig::new(
                "127.0.0.1:0".parse().unwrap(),
                "pki".into(),
                limits,
                false,
                false,
            )
        };
        assert!(limits(|_| {}).is_ok());
        let err = limits(|l| l.max_sessions = 0).unwrap_err();
        assert!(err.contains("opcua_max_sessions"), "{err}");
        let err = limits(|l| l.max_message_size = 100).unwrap_err();
        assert!(err.contains("opcua_max_message_size"), "{err}");
        let err = limits(|l| l.session_timeout = Duration::from_millis(10)).unwrap_err();
        assert!(err.contains("opcua_session_timeout_ms"), "{err}");
    }

    #[test]
    fn the_pki_lives_in_the_data_directory() {
        assert_eq!(
            default_pki_dir(Some(std::path::Path::new("/var/lib/candeck"))),
            PathBuf::from("/var/lib/candeck/opcua-pki")
        );
        assert_eq!(default_pki_dir(None), PathBuf::from("opcua-pki"));
    }
}
