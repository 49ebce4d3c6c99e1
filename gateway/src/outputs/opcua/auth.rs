//! Who may open a session: anonymous clients (when allowed) and the users of
//! `users_file`; refusals are counted, logged at most once per
//! [`WARN_PERIOD`] with the number suppressed, and a refused password is answered
//! after [`REFUSAL_DELAY`].

use std::sync::{Arc, Mutex};
use std::time::Duration;

use async_trait::async_trait;
use millgate_config::OpcUaUser;
use opcua::crypto::SecurityPolicy;
use opcua::server::authenticator::{
    user_pass_security_policy_id, AuthManager, Password, UserToken,
};
use opcua::server::ServerEndpoint;
use opcua::types::{Error, StatusCode, UAString, UserTokenPolicy, UserTokenType};

use super::status::{count, OpcUaCounters};
use crate::warn_limit::{WarnLimit, WARN_PERIOD};

/// How long a refused password waits for its answer: guesses one at a time go at
/// one a second, not dozens (round-4 audit, finding 8).
const REFUSAL_DELAY: Duration = Duration::from_secs(1);

/// The policy id of anonymous tokens that async-opcua's session service expects.
const POLICY_ID_ANONYMOUS: &str = "anonymous";
/// Prefix of a signed-in user's token (never the anonymous token's id).
const USER_TOKEN_PREFIX: &str = "user:";

/// The session's user name, `None` for an anonymous session.
pub(crate) fn user_name(token: &UserToken) -> Option<&str> {
    token.0.strip_prefix(USER_TOKEN_PREFIX)
}

/// The server's [`AuthManager`]: anonymous sessions when `anonymous`, user name and
/// password against `users` (compared in constant time), nothing else.
pub(crate) struct Users {
    anonymous: bool,
    users: Vec<OpcUaUser>,
    counters: Arc<OpcUaCounters>,
    refusals: Mutex<WarnLimit>,
}

impl Users {
    pub(crate) fn new(
        anonymous: bool,
        users: Vec<OpcUaUser>,
        counters: Arc<OpcUaCounters>,
    ) -> Self {
        Self {
            anonymous,
            users,
            counters,
            refusals: Mutex::new(WarnLimit::new(WARN_PERIOD)),
        }
    }

    /// One more refusal: counted; `Some(suppressed)` when it is to be logged.
    fn refused(&self) -> Option<u64> {
        count(&self.counters.identities_refused);
        crate::lock(&self.refusals).occurred(tokio::time::Instant::now())
    }
}

/// Whether `a` and `b` are equal, in a time that does not depend on where they differ.
fn same_secret(a: &[u8], b: &[u8]) -> bool {
    let mut difference = u8::from(a.len() != b.len());
    for (x, y) in a.iter().zip(b) {
        difference |= x ^ y;
    }
    difference == 0
}

#[async_trait]
impl AuthManager for Users {
    async fn authenticate_anonymous_token(&self, _endpoint: &ServerEndpoint) -> Result<(), Error> {
        if self.anonymous {
            Ok(())
        } else {
            if let Some(suppressed) = self.refused() {
                tracing::warn!(
                    suppressed,
                    "OPC UA anonymous session refused (outputs.opcua.anonymous = false)"
                );
            }
            Err(Error::new(
                StatusCode::BadIdentityTokenRejected,
                "anonymous sessions are not allowed",
            ))
        }
    }

    async fn authenticate_username_identity_token(
        &self,
        _endpoint: &ServerEndpoint,
        username: &str,
        password: &Password,
    ) -> Result<UserToken, Error> {
        let found = self.users.iter().find(|user| user.name == username);
        // Compare against something either way, so an unknown name takes as long.
        let expected = found.map_or("", |user| user.password.as_str());
        if found.is_some() && same_secret(expected.as_bytes(), password.get().as_bytes()) {
            return Ok(UserToken(format!("{USER_TOKEN_PREFIX}{username}")));
        }
        if let Some(suppressed) = self.refused() {
            tracing::warn!(user = %username, suppressed, "OPC UA sign-in refused: unknown user or wrong password");
        }
        tokio::time::sleep(REFUSAL_DELAY).await;
        Err(Error::new(
            StatusCode::BadUserAccessDenied,
            "unknown user or wrong password",
        ))
    }

    fn user_token_policies(&self, endpoint: &ServerEndpoint) -> Vec<UserTokenPolicy> {
        let mut policies = Vec::new();
        if self.anonymous {
            policies.push(UserTokenPolicy {
                policy_id: UAString::from(POLICY_ID_ANONYMOUS),
                token_type: UserTokenType::Anonymous,
                issued_token_type: UAString::null(),
                issuer_endpoint_url: UAString::null(),
                security_policy_uri: UAString::null(),
            });
        }
        if !self.users.is_empty() {
            // Passwords are encrypted with the server's certificate whatever the
            // endpoint's own security (the endpoints ask Basic256Sha256 for them).
            policies.push(UserTokenPolicy {
                policy_id: user_pass_security_policy_id(endpoint),
                token_type: UserTokenType::UserName,
                issued_token_type: UAString::null(),
                issuer_endpoint_url: UAString::null(),
                security_policy_uri: UAString::from(endpoint.password_security_policy().to_uri()),
            });
        }
        policies
    }
}

/// The password policy every endpoint asks for.
pub(crate) const PASSWORD_POLICY: SecurityPolicy = SecurityPolicy::Basic256Sha256;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn secrets_compare_whole() {
        assert!(same_secret(b"s3cret", b"s3cret"));
        assert!(!same_secret(b"s3cret", b"s3cres"));
        assert!(!same_secret(b"s3cret", b"s3cret!"));
        assert!(!same_secret(b"", b"x"));
        assert!(same_secret(b"", b""));
    }

    #[test]
    fn user_tokens_are_never_anonymous() {
        let token = UserToken(format!("{USER_TOKEN_PREFIX}ANONYMOUS"));
        assert!(!token.is_anonymous());
        assert_eq!(user_name(&token), Some("ANONYMOUS"));
        assert_eq!(user_name(&UserToken("ANONYMOUS".into())), None);
    }
}
