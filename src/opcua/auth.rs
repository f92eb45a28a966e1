//! Who may do what over OPC UA: anyone who reaches the server reads (an anonymous session);
//! the users of the users file also command (they log in with their password or certificate).
//! A method called in an anonymous session is refused (`BadUserAccessDenied`) before it runs,
//! and the method nodes show such a session `UserExecutable = false`.

use std::sync::Arc;
use std::time::{Duration, Instant};

use async_trait::async_trait;
use opcua::crypto::{SecurityPolicy, Thumbprint};
use opcua::server::ServerEndpoint;
use opcua::server::authenticator::{
    AuthManager, Password, UserToken, user_pass_security_policy_id, user_pass_security_policy_uri,
};
use opcua::types::{Error, NodeId, StatusCode, UAString, UserTokenPolicy, UserTokenType};
use tracing::{info, warn};

use super::users::Users;

/// The user token policy ids the server's session activation checks tokens against (they are
/// the server crate's own, which it does not export).
const POLICY_ID_ANONYMOUS: &str = "anonymous";
const POLICY_ID_X509: &str = "x509";

/// How long a refused login waits before it answers: guessing passwords one connection at a
/// time stays slow.
const REFUSAL_DELAY: Duration = Duration::from_millis(300);

/// The most refused logins logged in a window; more are counted and summarised.
const LOGGED_REFUSALS: u64 = 5;
/// The window of [`LOGGED_REFUSALS`].
const REFUSAL_WINDOW: Duration = Duration::from_secs(10);

/// The server's authenticator.
pub struct Auth {
    users: Option<Arc<Users>>,
    refusals: std::sync::Mutex<RefusalLog>,
}

struct RefusalLog {
    since: Instant,
    count: u64,
}

impl Auth {
    /// Anonymous sessions read; `users` (if any) also command.
    pub fn new(users: Option<Users>) -> Auth {
        Auth {
            users: users.map(Arc::new),
            refusals: std::sync::Mutex::new(RefusalLog {
                since: Instant::now(),
                count: 0,
            }),
        }
    }

    /// Logs a refused login — the first few of each window, then how many more there were.
    fn refused(&self, what: &str) {
        let mut log = self.refusals.lock().unwrap_or_else(|p| p.into_inner());
        if log.since.elapsed() > REFUSAL_WINDOW {
            if log.count > LOGGED_REFUSALS {
                warn!(
                    "OPC UA: {} more logins refused in the last {} s",
                    log.count - LOGGED_REFUSALS,
                    REFUSAL_WINDOW.as_secs()
                );
            }
            log.since = Instant::now();
            log.count = 0;
        }
        log.count += 1;
        if log.count <= LOGGED_REFUSALS {
            warn!("OPC UA: login refused: {what}");
        }
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
                Ok(UserToken(user.name.clone()))
            }
            None => {
                self.refused(&format!(
                    "user \"{}\": unknown user or wrong password",
                    crate::config::shorten(username)
                ));
                tokio::time::sleep(REFUSAL_DELAY).await;
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
                self.refused("a certificate no user of the users file has");
                tokio::time::sleep(REFUSAL_DELAY).await;
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
            // security (the endpoint's password policy).
            policies.push(UserTokenPolicy {
                policy_id: user_pass_security_policy_id(endpoint),
                token_type: UserTokenType::UserName,
                issued_token_type: UAString::null(),
                issuer_endpoint_url: UAString::null(),
                security_policy_uri: user_pass_security_policy_uri(endpoint),
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
