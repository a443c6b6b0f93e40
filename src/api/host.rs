//! The `Host` check against DNS rebinding (issue 19, point 3).
//!
//! A web page at `http://evil.example:8080` whose name its owner points at
//! `127.0.0.1` (or at the gateway's LAN address) after the page loaded is,
//! for the browser, the same origin as the gateway: the origin check of
//! [`super::auth`] cannot tell, since `Origin` and `Host` then agree. What
//! gives such a page away is the `Host` it sends: a name the gateway is not
//! served as. So every request, on every route (the API, `/stream`,
//! `/metrics`, `/cia309-5`, the dashboard, the docs), must be sent to:
//!
//! - a loopback name: `localhost` or a name under `.localhost` (RFC 6761:
//!   browsers resolve them to loopback themselves);
//! - an IP address (the listen address, `127.0.0.1`, `[::1]`, any address
//!   the gateway is reached at): a page can only send `Host: 192.0.2.7` when
//!   it was itself loaded from `192.0.2.7`, that is from the gateway, so an
//!   address cannot be rebound;
//! - a name listed in `allowed_hosts` (`--allowed-host`), or anything when
//!   that list holds `*`.
//!
//! The check applies with tokens too: a token kept in a browser (the
//! dashboard keeps it in its storage) is not sent to a rebound name, but an
//! open gateway and `/health` are reachable without one, and the rule is
//! simpler when it has no exception. A request without `Host` (HTTP/1.0,
//! tools) is let through: browsers always send it.

use std::net::IpAddr;

use axum::extract::Request;
use axum::http::header;
use axum::response::{IntoResponse, Response};

use super::AppError;

/// The names the gateway answers to besides loopback names and addresses.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct AllowedHosts {
    /// `*` was listed: every `Host` passes.
    any: bool,
    /// Lower case, without a port or a final dot.
    names: Vec<String>,
}

impl AllowedHosts {
    /// The list of `allowed_hosts`: host names (`gateway.plant.example`),
    /// without scheme, port or path, or `*` for any.
    pub fn new(entries: &[String]) -> Result<Self, String> {
        let mut hosts = Self::default();
        for entry in entries {
            let entry = entry.trim();
            if entry == "*" {
                hosts.any = true;
                continue;
            }
            let name = entry.trim_end_matches('.').to_ascii_lowercase();
            let valid = !name.is_empty()
                && name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '.' | '_'));
            if !valid {
                return Err(format!(
                    "allowed_hosts: '{entry}' is no host name like gateway.plant.example (no scheme, port or path; '*' allows any)"
                ));
            }
            hosts.names.push(name);
        }
        Ok(hosts)
    }

    /// Whether every `Host` passes (`*` listed).
    pub fn any(&self) -> bool {
        self.any
    }

    /// The names listed (without `*`).
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Whether a request sent with this `Host` header value is for the
    /// gateway.
    pub fn allows(&self, host: &str) -> bool {
        if self.any {
            return true;
        }
        let Some(name) = host_name(host) else {
            return false;
        };
        if name.parse::<IpAddr>().is_ok() {
            return true;
        }
        let name = name.trim_end_matches('.').to_ascii_lowercase();
        name == "localhost" || name.ends_with(".localhost") || self.names.contains(&name)
    }
}

/// The host of a `Host` value, without its port: `[::1]:8080` → `::1`,
/// `localhost:8080` → `localhost`. `None` when it is no host.
fn host_name(value: &str) -> Option<&str> {
    let value = value.trim();
    if let Some(rest) = value.strip_prefix('[') {
        let (address, after) = rest.split_once(']')?;
        return (after.is_empty() || after.strip_prefix(':').is_some_and(is_port))
            .then_some(address);
    }
    let name = match value.split_once(':') {
        Some((name, port)) if is_port(port) => name,
        Some(_) => return None,
        None => value,
    };
    (!name.is_empty()).then_some(name)
}

fn is_port(text: &str) -> bool {
    !text.is_empty() && text.len() <= 5 && text.bytes().all(|b| b.is_ascii_digit())
}

/// 421 `host_not_allowed` for a request sent to a name the gateway is not
/// served as: the first thing the guard ([`super::auth::guard`]) asks,
/// before anything else looks at the request (and so before it knows who
/// sent it).
pub fn refusal(allowed: &AllowedHosts, request: &Request) -> Option<Response> {
    let from_header = request
        .headers()
        .get(header::HOST)
        .map(|value| value.to_str().unwrap_or("\u{fffd}"));
    let host = from_header.or_else(|| request.uri().authority().map(|a| a.as_str()))?;
    (!allowed.allows(host)).then(|| {
        AppError::HostNotAllowed(format!(
            "this gateway is not served as '{host}': a page under a foreign name may be a DNS rebinding attack; allowed_hosts (--allowed-host) lists the names it answers to besides localhost and IP addresses"
        ))
        .into_response()
    })
}

#[cfg(test)]
mod tests;
