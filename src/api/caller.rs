//! Who a REST request acts for, as the gateway's operations take it
//! ([`RestCaller`]); the object its audit entry names, as its handler
//! resolved it ([`AuditItem`]); a response whose handler audited it
//! ([`AuditedByHandler`]).

use std::convert::Infallible;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};

use axum::extract::{ConnectInfo, FromRequestParts};
use axum::http::request::Parts;

use super::auth::Identity;
use crate::gateway::DoorRequest;
use crate::gateway::{Caller, Channel};

/// The request's caller: the token the guard found (`anonymous` without
/// one, or on a gateway without tokens), from the client's address when
/// the server knows it.
#[derive(Debug, Clone)]
pub struct RestCaller(pub Caller);

impl<S: Send + Sync> FromRequestParts<S> for RestCaller {
    type Rejection = Infallible;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, Infallible> {
        let identity = parts.extensions.get::<Identity>();
        let mut caller = Caller::new(
            Channel::Rest,
            identity.map_or_else(|| "anonymous".to_string(), |id| id.name.clone()),
            identity.and_then(|id| id.role),
        );
        if let Some(ConnectInfo(peer)) = parts.extensions.get::<ConnectInfo<SocketAddr>>() {
            caller = caller.with_peer(peer.to_string());
        }
        // The request as the audit layer knows it: the operations' rows
        // carry its words and come back to it for the status.
        if let Some(door) = parts.extensions.get::<DoorRequest>() {
            caller = caller.with_door(door.clone());
        }
        Ok(Self(caller))
    }
}

/// The object a request acts on as its handler resolved it (an EDS name or
/// `6041h` in the path is `0x6041:0` here, as the other doors log it); the
/// audit layer puts one in every audited request's extensions and takes
/// it, when set, for the entry's item instead of the path's words.
#[derive(Debug, Clone, Default)]
pub struct AuditItem(Arc<Mutex<Option<String>>>);

impl AuditItem {
    pub fn set(&self, item: String) {
        *self.0.lock().unwrap_or_else(|poison| poison.into_inner()) = Some(item);
    }

    pub fn take(&self) -> Option<String> {
        self.0
            .lock()
            .unwrap_or_else(|poison| poison.into_inner())
            .take()
    }
}

/// Put in a response whose handler wrote the request's audit entry itself
/// (a CiA 309-5 command, as CiA 309-3's): the audit layer writes none, even
/// for a refusal (401, 403, 429) it would otherwise take for the guard's.
#[derive(Debug, Clone, Copy)]
pub struct AuditedByHandler;
