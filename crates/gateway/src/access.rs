//! Tokens and roles: who may do what, the same for every adapter (the REST
//! API's guard in `crate::api::auth`, the CiA 309-3 `auth` line). A token
//! has a name, a role (what each operation needs of one:
//! [`crate::policy::Operation::required_role`]) and a secret; `CANDECK_TOKENS` lists them as
//! `NAME:ROLE:TOKEN`. And the one write rate limit ([`WriteLimiter`]) that
//! REST, CiA 309-5 and CiA 309-3 take their writes from, per token name.

use std::collections::HashMap;
use std::sync::Mutex;
use std::time::Duration;

use serde::Serialize;
use tokio::time::Instant;

/// What a token may do; each role may do what the ones before it may.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// Reads, the stream and STOP ALL.
    Viewer,
    /// Motion, LEDs, NMT, object writes, SYNC, raw frames, loggers.
    Operator,
    /// PDO configuration, store/restore, DCF restore, program download,
    /// recording, LSS, virtual devices, the EDS catalog.
    Admin,
}

impl Role {
    pub fn name(self) -> &'static str {
        match self {
            Self::Viewer => "viewer",
            Self::Operator => "operator",
            Self::Admin => "admin",
        }
    }
}

impl std::str::FromStr for Role {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        match text.trim() {
            "viewer" => Ok(Self::Viewer),
            "operator" => Ok(Self::Operator),
            "admin" => Ok(Self::Admin),
            other => Err(format!(
                "unknown role '{}' (a role is viewer, operator or admin)",
                shown(other)
            )),
        }
    }
}

impl std::fmt::Display for Role {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A field of a token entry as an error message may show it: hidden when
/// it could be a secret (as long as one, of its alphabet), so that an entry
/// with its fields swapped (`plc:TOKEN:operator`) never puts the secret in
/// a terminal or a journal.
pub(crate) fn shown(field: &str) -> String {
    let could_be_secret = field.len() >= MIN_TOKEN_LEN
        && field
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-._~".contains(c));
    if could_be_secret {
        format!("<hidden, {} characters>", field.len())
    } else {
        field.to_string()
    }
}

/// One configured token.
#[derive(Clone)]
pub struct Token {
    pub name: String,
    pub role: Role,
    secret: Vec<u8>,
}

impl std::fmt::Debug for Token {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Never the secret, not even in a debug print.
        f.debug_struct("Token")
            .field("name", &self.name)
            .field("role", &self.role)
            .finish_non_exhaustive()
    }
}

/// The shortest token accepted: 20 characters of a 64-letter alphabet are
/// 120 bits (`openssl rand -hex 32` gives 64).
pub(crate) const MIN_TOKEN_LEN: usize = 20;

impl Token {
    /// A token, checked: a name of letters, digits, `-_.@`; a secret of at
    /// least `MIN_TOKEN_LEN` characters of `A-Za-z0-9-._~` (so that it
    /// fits a header and a WebSocket subprotocol unquoted), not one that
    /// repeats a few characters.
    pub fn new(name: &str, role: Role, secret: &str) -> Result<Self, String> {
        // The name as errors show it: a name that could be a secret is a
        // secret in the wrong field.
        let name_shown = shown(name);
        let name_shown = name_shown.as_str();
        if name.is_empty()
            || !name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "-_.@".contains(c))
        {
            return Err(format!(
                "token name '{name_shown}' is not a name: letters, digits, '-', '_', '.' and '@' only"
            ));
        }
        if let Some(bad) = secret
            .chars()
            .find(|c| !(c.is_ascii_alphanumeric() || "-._~".contains(*c)))
        {
            return Err(format!(
                "token {name_shown}: the character {bad:?} is not allowed (A-Z a-z 0-9 - . _ ~ only; openssl rand -hex 32 makes one)"
            ));
        }
        if secret.len() < MIN_TOKEN_LEN {
            return Err(format!(
                "token {name_shown}: {} characters is too weak, at least {MIN_TOKEN_LEN} (openssl rand -hex 32 makes one)",
                secret.len()
            ));
        }
        let distinct = secret
            .bytes()
            .collect::<std::collections::BTreeSet<u8>>()
            .len();
        if distinct < 8 {
            return Err(format!(
                "token {name_shown}: too weak, it repeats {distinct} characters (openssl rand -hex 32 makes one)"
            ));
        }
        Ok(Self {
            name: name.to_string(),
            role,
            secret: secret.as_bytes().to_vec(),
        })
    }

    /// `NAME:ROLE:TOKEN`, as `CANDECK_TOKENS` lists them.
    pub fn parse_entry(entry: &str) -> Result<Self, String> {
        let mut parts = entry.trim().splitn(3, ':');
        match (parts.next(), parts.next(), parts.next()) {
            (Some(name), Some(role), Some(secret)) => {
                // The field is not shown: the fields may be swapped, and
                // it the secret.
                let role = role.parse().map_err(|_| {
                    format!(
                        "token {}: its second field is not a role (viewer, operator or admin); an entry is NAME:ROLE:TOKEN",
                        shown(name)
                    )
                })?;
                Self::new(name, role, secret)
            }
            _ => Err("a token is NAME:ROLE:TOKEN".to_string()),
        }
    }
}

/// Whether `given` equals `secret`, in a time that depends on the length of
/// `secret` only (never on where they first differ, nor on `given`).
pub fn constant_time_eq(given: &[u8], secret: &[u8]) -> bool {
    let mut diff = u8::from(given.len() != secret.len());
    for (i, byte) in secret.iter().enumerate() {
        diff |= given.get(i).copied().unwrap_or(!*byte) ^ byte;
    }
    std::hint::black_box(diff) == 0
}

/// The gateway's tokens. None: the gateway is open.
#[derive(Debug, Clone, Default)]
pub struct Tokens(Vec<Token>);

impl Tokens {
    pub fn new(tokens: Vec<Token>) -> Self {
        Self(tokens)
    }

    /// No two tokens of one name or one secret.
    pub fn check(tokens: &[Token]) -> Result<(), String> {
        for (i, token) in tokens.iter().enumerate() {
            for other in &tokens[..i] {
                if other.name == token.name {
                    return Err(format!("two tokens are named '{}'", token.name));
                }
                if constant_time_eq(&token.secret, &other.secret) {
                    return Err(format!(
                        "tokens {} and {} are the same token",
                        other.name, token.name
                    ));
                }
            }
        }
        Ok(())
    }

    /// Whether requests need a token.
    pub fn required(&self) -> bool {
        !self.0.is_empty()
    }

    /// The token whose secret is `given`, comparing with every token (so
    /// that the time says nothing of which one matched).
    pub fn find(&self, given: &str) -> Option<&Token> {
        let mut found = None;
        for token in &self.0 {
            if constant_time_eq(given.as_bytes(), &token.secret) {
                found = Some(token);
            }
        }
        found
    }

    /// The name and role of the token `given`, compared in constant time.
    pub fn authenticate(&self, given: &str) -> Option<(String, Role)> {
        self.find(given)
            .map(|token| (token.name.clone(), token.role))
    }

    /// Whether a client holding `held` (`None`: no valid token) may do what
    /// needs `needed`; on an open gateway, anyone may.
    pub fn allows(&self, held: Option<Role>, needed: Role) -> bool {
        !self.required() || held.is_some_and(|role| role >= needed)
    }
}

impl std::ops::Deref for Tokens {
    type Target = [Token];

    fn deref(&self) -> &[Token] {
        &self.0
    }
}

/// The per-token rate limit on writes: a bucket of `burst` writes that
/// refills at `per_second`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RateLimit {
    pub per_second: f64,
    pub burst: u32,
}

impl Default for RateLimit {
    /// 10 writes a second, bursts of 40: more than a person clicks, less
    /// than a runaway script.
    fn default() -> Self {
        Self {
            per_second: 10.0,
            burst: 40,
        }
    }
}

/// The write buckets of every token, one per token name, shared by every
/// adapter: a token that sends its writes over REST, CiA 309-5 and CiA
/// 309-3 at once draws on one bucket (issue 19, point 7).
#[derive(Debug, Default)]
pub(crate) struct WriteLimiter {
    /// `None`: writes are not rate limited.
    limit: Option<RateLimit>,
    buckets: Mutex<HashMap<String, Bucket>>,
}

#[derive(Debug, Clone, Copy)]
struct Bucket {
    tokens: f64,
    at: Instant,
}

impl WriteLimiter {
    pub(crate) fn new(limit: Option<RateLimit>) -> Self {
        Self {
            limit,
            buckets: Mutex::new(HashMap::new()),
        }
    }

    /// Takes one write from `who`'s bucket, or says how long until one is
    /// there.
    pub(crate) fn take(&self, who: &str) -> Result<(), Duration> {
        let Some(limit) = self.limit else {
            return Ok(());
        };
        let now = Instant::now();
        let burst = f64::from(limit.burst);
        let mut buckets = self
            .buckets
            .lock()
            .unwrap_or_else(|poison| poison.into_inner());
        let bucket = buckets.entry(who.to_string()).or_insert(Bucket {
            tokens: burst,
            at: now,
        });
        let refilled = now.duration_since(bucket.at).as_secs_f64() * limit.per_second;
        bucket.tokens = (bucket.tokens + refilled).min(burst);
        bucket.at = now;
        if bucket.tokens >= 1.0 {
            bucket.tokens -= 1.0;
            Ok(())
        } else {
            Err(Duration::from_secs_f64(
                (1.0 - bucket.tokens) / limit.per_second,
            ))
        }
    }

    /// [`WriteLimiter::take`] as the gateway's error: `rate_limited`, with
    /// the whole seconds to wait.
    pub(crate) fn take_or_refuse(&self, who: &str) -> Result<(), crate::GatewayError> {
        self.take(who).map_err(|wait| {
            let seconds = wait.as_secs_f64().ceil().max(1.0) as u64;
            crate::GatewayError::RateLimited {
                message: format!(
                    "token {who} sends writes faster than allowed; try again in {seconds} s"
                ),
                retry_after_s: seconds,
            }
        })
    }
}
