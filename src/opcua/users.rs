//! Who a session is: a user name and password checked against candeck's
//! tokens (the token's name is the user, its secret the password; the
//! role is the token's), or anonymous where REST would answer an
//! anonymous request ([`Logins`]). The session's [`Caller`] is built from
//! it for every operation.

use async_trait::async_trait;
use opcua::crypto::SecurityPolicy;
use opcua::server::ServerEndpoint;
use opcua::server::authenticator::{
    AuthManager, Password, UserToken, user_pass_security_policy_id,
};
use opcua::types::{Error, StatusCode, UAString, UserTokenPolicy, UserTokenType};

use super::config::Logins;
use crate::gateway::{Caller, Channel, Tokens};

/// The policy id of anonymous logins, as the server checks it.
const ANONYMOUS_POLICY_ID: &str = "anonymous";

/// candeck's tokens as OPC UA identities.
pub struct TokenUsers {
    tokens: Tokens,
    logins: Logins,
}

impl TokenUsers {
    pub fn new(tokens: Tokens, logins: Logins) -> Self {
        Self { tokens, logins }
    }

    /// The user `name` with password `password`: the token's name when the
    /// secret is that token's (compared in constant time with every token,
    /// then the name checked, so that neither says which part was wrong).
    pub fn check(&self, name: &str, password: &str) -> Option<String> {
        let token = self.tokens.find(password)?;
        (token.name == name).then(|| token.name.clone())
    }

    /// The caller a session of `user` acts as (`anonymous` without one, or
    /// on a gateway without tokens).
    pub fn caller(&self, user: &UserToken) -> Caller {
        if user.is_anonymous() {
            return Caller::new(Channel::Opcua, "anonymous", None);
        }
        let role = self
            .tokens
            .iter()
            .find(|token| token.name == user.0)
            .map(|token| token.role);
        Caller::new(Channel::Opcua, user.0.clone(), role)
    }
}

#[async_trait]
impl AuthManager for TokenUsers {
    async fn authenticate_anonymous_token(&self, _endpoint: &ServerEndpoint) -> Result<(), Error> {
        if self.logins.anonymous {
            return Ok(());
        }
        Err(Error::new(
            StatusCode::BadIdentityTokenRejected,
            "anonymous sessions are only served on loopback by a gateway without tokens: log in \
             with a token's name and secret",
        ))
    }

    async fn authenticate_username_identity_token(
        &self,
        _endpoint: &ServerEndpoint,
        username: &str,
        password: &Password,
    ) -> Result<UserToken, Error> {
        if !self.logins.users {
            return Err(Error::new(
                StatusCode::BadIdentityTokenRejected,
                "this gateway has no tokens: log in anonymously",
            ));
        }
        match self.check(username, password.get()) {
            Some(name) => Ok(UserToken(name)),
            None => {
                tracing::warn!("opcua: refused a login as '{username}': no such token");
                Err(Error::new(
                    StatusCode::BadUserAccessDenied,
                    "no token has this name and secret",
                ))
            }
        }
    }

    fn user_token_policies(&self, endpoint: &ServerEndpoint) -> Vec<UserTokenPolicy> {
        let mut policies = Vec::new();
        if self.logins.anonymous {
            policies.push(UserTokenPolicy {
                policy_id: UAString::from(ANONYMOUS_POLICY_ID),
                token_type: UserTokenType::Anonymous,
                issued_token_type: UAString::null(),
                issuer_endpoint_url: UAString::null(),
                security_policy_uri: UAString::null(),
            });
        }
        // A password is never sent in clear: over the unsecured endpoint
        // (loopback only) it is encrypted with the server's key by the
        // endpoint's password policy (Basic256Sha256), as over the others.
        if self.logins.users {
            let unsecured = endpoint.security_policy() == SecurityPolicy::None;
            policies.push(UserTokenPolicy {
                policy_id: user_pass_security_policy_id(endpoint),
                token_type: UserTokenType::UserName,
                issued_token_type: UAString::null(),
                issuer_endpoint_url: UAString::null(),
                security_policy_uri: if unsecured {
                    UAString::from(endpoint.password_security_policy().to_uri())
                } else {
                    UAString::null()
                },
            });
        }
        policies
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gateway::{Role, Token};
    use opcua::server::ANONYMOUS_USER_TOKEN_ID;

    fn users() -> TokenUsers {
        TokenUsers::new(
            Tokens::new(vec![
                Token::new("line-hmi", Role::Operator, "0123456789abcdefghij").unwrap(),
                Token::new("scada", Role::Viewer, "zyxwvutsrq9876543210").unwrap(),
            ]),
            Logins {
                users: true,
                anonymous: false,
                unsecured_endpoint: false,
            },
        )
    }

    #[test]
    fn a_token_logs_in_by_its_name_and_secret_with_its_role() {
        let users = users();
        assert_eq!(
            users.check("line-hmi", "0123456789abcdefghij").as_deref(),
            Some("line-hmi")
        );
        // Another token's secret, or a wrong one, is no login.
        assert_eq!(users.check("line-hmi", "zyxwvutsrq9876543210"), None);
        assert_eq!(users.check("line-hmi", "wrong"), None);
        let caller = users.caller(&UserToken("scada".into()));
        assert_eq!(caller.channel, Channel::Opcua);
        assert_eq!(caller.who, "scada");
        assert_eq!(caller.role, Some(Role::Viewer));
        let anonymous = users.caller(&UserToken(ANONYMOUS_USER_TOKEN_ID.into()));
        assert_eq!(
            (anonymous.who.as_str(), anonymous.role),
            ("anonymous", None)
        );
    }

    #[tokio::test]
    async fn anonymous_is_refused_where_the_logins_say_so() {
        let users = users();
        let endpoint = ServerEndpoint::new_none("/", &[]);
        assert!(users.authenticate_anonymous_token(&endpoint).await.is_err());
        let policies = users.user_token_policies(&endpoint);
        assert!(
            policies
                .iter()
                .all(|policy| policy.token_type == UserTokenType::UserName)
        );
        let open = TokenUsers::new(
            Tokens::default(),
            Logins {
                users: false,
                anonymous: true,
                unsecured_endpoint: true,
            },
        );
        assert!(open.authenticate_anonymous_token(&endpoint).await.is_ok());
        let refused = open
            .authenticate_username_identity_token(&endpoint, "x", &Password::new("y".into()))
            .await;
        assert!(refused.is_err());
    }
}
