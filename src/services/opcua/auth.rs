//! Who may do what over OPC UA: anyone who reaches the server reads (an anonymous session);
//! the users of the users file also command (they log in with their password or certificate).
//! A method called in an anonymous session is refused (`BadUserAccessDenied`) before it runs,
//! and the method nodes show such a session `UserExecutable = false`.

use std::sync::Arc;
use std::time::Instant;

use async_trait::async_trait;
use opcua::crypto::{SecurityPolicy, Thumbprint};
use opcua::server::ServerEndpoint;
use opcua::server::authenticator::{AuthManager, Password, UserToken, user_pass_security_policy_id};
use opcua::types::{Error, NodeId, StatusCode, UAString, UserTokenPolicy, UserTokenType};
use tracing::info;

use super::users::Users;
use crate::runtime::backoff::Backoff;
use crate::runtime::log_limit::Limited;

/// The user token policy ids the server's session activation checks tokens against (they are
/// the server crate's own, which it does not export).
const POLICY_ID_ANONYMOUS: &str = "anonymous";
const POLICY_ID_X509: &str = "x509";

/// The server's authenticator.
pub struct Auth {
    users: Option<Arc<Users>>,
    /// Refused logins per user name, and of all names together (the server sees no client
    /// address: every connection reaches it through the gate, from loopback).
    per_user: Backoff<String>,
    all: Backoff<()>,
    /// One line per user name per interval.
    refusals: Limited<String>,
}

impl Auth {
    /// Anonymous sessions read; `users` (if any) also command.
    pub fn new(users: Option<Users>) -> Auth {
        Auth {
            users: users.map(Arc::new),
            per_user: Backoff::default(),
            all: Backoff::default(),
            refusals: Limited::new("OPC UA: logins refused"),
        }
    }

    /// A refused login of `name` (`what` says why): logged at most once per name and interval,
    /// and answered after the back-off of that name or of all refusals, whichever is longer —
    /// a guesser's answers slow down however many clients guess at once, and the right
    /// credentials are answered at once whatever was guessed before.
    async fn refused(&self, name: &str, what: String) {
        self.refusals
            .warn(name.to_string(), || format!("OPC UA: login refused: {what}"));
        let now = Instant::now();
        let wait = self
            .per_user
            .refused(&name.to_string(), now)
            .max(self.all.refused(&(), now));
        tokio::time::sleep(wait).await;
    }
}

#[async_trait]
impl AuthManager for Auth {
    async fn authenticate_anonymous_token(&self, _endpoint: &ServerEndpoint) -> Result<(), Error> {
        Ok(())
    }

    async fn authenticate_username_identity_token(
        &self,
        _endpoint: &ServerEndpoint,
        username: &str,
        password: &Password,
    ) -> Result<UserToken, Error> {
        match self
            .users
            .as_ref()
            .and_then(|u| u.check_password(username, password.get()))
        {
            Some(user) => {
                info!("OPC UA: user \"{}\" logged in (password)", user.name);
                self.per_user.accepted(&user.name);
                Ok(UserToken(user.name.clone()))
            }
            None => {
                let name = crate::runtime::config::shorten(username);
                self.refused(&name, format!("user \"{name}\": unknown user or wrong password"))
                    .await;
                Err(Error::new(
                    StatusCode::BadUserAccessDenied,
                    "unknown user or wrong password",
                ))
            }
        }
    }

    async fn authenticate_x509_identity_token(
        &self,
        _endpoint: &ServerEndpoint,
        signing_thumbprint: &Thumbprint,
    ) -> Result<UserToken, Error> {
        match self
            .users
            .as_ref()
            .and_then(|u| u.check_certificate(signing_thumbprint))
        {
            Some(user) => {
                info!("OPC UA: user \"{}\" logged in (certificate)", user.name);
                Ok(UserToken(user.name.clone()))
            }
            None => {
                self.refused("(a certificate)", "a certificate no user of the users file has".into())
                    .await;
                Err(Error::new(
                    StatusCode::BadIdentityTokenRejected,
                    "the certificate is no user's",
                ))
            }
        }
    }

    /// Only users command: an anonymous session reads.
    fn is_user_executable(&self, token: &UserToken, _method_id: &NodeId) -> bool {
        !token.is_anonymous()
    }

    fn user_token_policies(&self, endpoint: &ServerEndpoint) -> Vec<UserTokenPolicy> {
        let mut policies = vec![UserTokenPolicy {
            policy_id: UAString::from(POLICY_ID_ANONYMOUS),
            token_type: UserTokenType::Anonymous,
            issued_token_type: UAString::null(),
            issuer_endpoint_url: UAString::null(),
            security_policy_uri: UAString::null(),
        }];
        let Some(users) = &self.users else {
            return policies;
        };
        if users.has_passwords() {
            // The password travels encrypted with the server's key whatever the channel's
            // security: the policy names the password's security policy (the unsecured
            // endpoint's is Basic256Sha256), so a client encrypts it — with no policy named, a
            // client takes the channel's, and on the unsecured endpoint sent it readable. A
            // password sent in clear is refused.
            let password_policy = endpoint.password_security_policy();
            policies.push(UserTokenPolicy {
                policy_id: user_pass_security_policy_id(endpoint),
                token_type: UserTokenType::UserName,
                issued_token_type: UAString::null(),
                issuer_endpoint_url: UAString::null(),
                security_policy_uri: if password_policy == SecurityPolicy::None {
                    UAString::null()
                } else {
                    UAString::from(password_policy.to_uri())
                },
            });
        }
        if users.has_certificates() {
            policies.push(UserTokenPolicy {
                policy_id: UAString::from(POLICY_ID_X509),
                token_type: UserTokenType::Certificate,
                issued_token_type: UAString::null(),
                issuer_endpoint_url: UAString::null(),
                security_policy_uri: UAString::from(SecurityPolicy::Basic256Sha256.to_uri()),
            });
        }
        policies
    }
}
