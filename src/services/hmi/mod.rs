//! The operator's screen: a web page served by the soft-PLC, off the cyclic path.
//!
//! - [`crate::runtime::frame`] (the core's): what the cycle publishes for the screen, wait-free.
//! - [`commands`]: the screen's commands, taken wait-free before each cycle into the `HMI_*`
//!   variables by a bus laid over the field bus.
//! - [`mechanism`]: the machine's links in its pose, drawn by its kinematics.
//! - [`server`]: the page and its WebSocket (axum, on the runtime's tokio runtime).
//! - [`access`]: who is served (Host, Origin) and who commands (the token).
//! - [`listener`]: the listening socket, with a bound on the connections it holds.
//! - [`jobs`]: the screen's jobs, planned off the cyclic thread; [`job_news`]: what became of
//!   them, for OPC UA's `JobRefused` condition.
//!
//! Loopback only by default; binding to another address needs a token, and commands need it
//! whenever one is set (see "The operator's screen" in the README).

pub mod access;
pub mod alarms;
pub mod commands;
pub mod cut;
pub mod job_news;
pub mod jobs;
pub mod listener;
pub mod mechanism;
mod served;
pub mod server;

use std::net::SocketAddr;

/// Where and how the screen is served.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct HmiOptions {
    /// The address to listen on.
    pub addr: SocketAddr,
    /// Commands need this token (`?token=` on the page's address, an `Authorization: Bearer`
    /// header or the page's cookie); without it a client watches.
    pub token: Option<String>,
    /// Origins besides the screen's own whose pages may open its WebSocket.
    pub allowed_origins: Vec<String>,
    /// WebSocket clients at once.
    pub max_clients: usize,
    /// The next ports tried when `addr`'s is taken: some for the default address (a second PLC
    /// on the same computer gets a screen of its own, and says where), none for one the user
    /// gave.
    pub next_ports: u16,
}

/// The next ports tried for the default address when its port is taken.
pub const DEFAULT_NEXT_PORTS: u16 = 9;

/// The default address: loopback, port 8080.
pub const DEFAULT_ADDR: &str = "127.0.0.1:8080";

/// The default bound on WebSocket clients.
pub const DEFAULT_MAX_CLIENTS: usize = 16;

impl HmiOptions {
    /// Refuses what must not be served: another address than loopback without a token (anyone
    /// who reaches the port could stop or jog the machine), a token that is empty, not
    /// printable or (beyond loopback) shorter than [`access::MIN_TOKEN_LEN`], an allowed origin
    /// that is not `scheme://host[:port]`.
    pub fn check(&self) -> Result<(), String> {
        if let Some(token) = &self.token {
            access::check_token(token, self.addr.ip().is_loopback()).map_err(|e| format!("--hmi-token: {e}"))?;
        }
        for origin in &self.allowed_origins {
            let valid = origin.split_once("://").is_some_and(|(scheme, host)| {
                matches!(scheme, "http" | "https") && !host.is_empty() && !host.contains(['/', '?', '#', ' ', '@'])
            });
            if !valid {
                return Err(format!(
                    "--hmi-allow-origin {origin}: an origin is scheme://host[:port], as a browser sends it (e.g. https://hmi.lab.example)"
                ));
            }
        }
        if self.max_clients == 0 {
            return Err("--hmi-max-clients: at least 1".into());
        }
        if !self.addr.ip().is_loopback() && self.token.is_none() {
            return Err(format!(
                "--hmi {}: serving the screen beyond this computer needs a token (--hmi-token TOKEN or \
                 --hmi-token-file FILE): without one, anyone who reaches the port could stop and jog the machine",
                self.addr
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_loopback_goes_without_a_token() {
        let at = |a: &str, token: Option<&str>| HmiOptions {
            next_ports: 0,
            addr: a.parse().expect("an address"),
            token: token.map(str::to_string),
            allowed_origins: Vec::new(),
            max_clients: DEFAULT_MAX_CLIENTS,
        };
        assert_eq!(at("127.0.0.1:8080", None).check(), Ok(()));
        assert_eq!(at("[::1]:8080", None).check(), Ok(()));
        assert!(
            at("0.0.0.0:8080", None)
                .check()
                .is_err_and(|e| e.contains("needs a token"))
        );
        assert_eq!(at("0.0.0.0:8080", Some("a-long-s3cret-token")).check(), Ok(()));
        assert_eq!(
            at("0.0.0.0:8080", Some("s3cret")).check(),
            Err(
                "--hmi-token: a token for a screen served beyond this computer needs at least 16 characters, got 6"
                    .into()
            )
        );
        assert_eq!(at("127.0.0.1:8080", Some("s3cret")).check(), Ok(()));
        assert!(
            at("127.0.0.1:8080", Some(" "))
                .check()
                .is_err_and(|e| e.contains("printable"))
        );
        let mut o = at("127.0.0.1:8080", None);
        o.allowed_origins = vec!["https://hmi.lab.example/page".into()];
        assert!(o.check().is_err_and(|e| e.contains("scheme://host[:port]")));
        o.allowed_origins = vec!["https://hmi.lab.example:8443".into()];
        assert_eq!(o.check(), Ok(()));
    }
}
