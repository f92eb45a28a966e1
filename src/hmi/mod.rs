//! The operator's screen (issue 17): a web page served by the soft-PLC, off the cyclic path.
//!
//! - [`frame`]: what the cycle publishes for the screen, wait-free.
//! - [`commands`]: the screen's commands, taken wait-free before each cycle into the `HMI_*`
//!   variables by a bus laid over the field bus.
//! - [`mechanism`]: the machine's links in its pose, drawn by its kinematics.
//! - [`server`]: the page and its WebSocket (axum, on the runtime's tokio runtime).
//!
//! Loopback only by default; binding to another address needs a token, and commands need it
//! whenever one is set (see "The operator's screen" in the README).

pub mod commands;
pub mod frame;
pub mod mechanism;
pub mod server;

use std::net::SocketAddr;

/// Where and how the screen is served.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct HmiOptions {
    /// The address to listen on.
    pub addr: SocketAddr,
    /// Commands need this token (`?token=` on the page's address); without it a client watches.
    pub token: Option<String>,
}

/// The default address: loopback, port 8080.
pub const DEFAULT_ADDR: &str = "127.0.0.1:8080";

impl HmiOptions {
    /// Refuses what must not be served: another address than loopback without a token (anyone
    /// who reaches the port could stop or jog the machine), or an empty token.
    pub fn check(&self) -> Result<(), String> {
        if self.token.as_deref().is_some_and(|t| t.trim().is_empty()) {
            return Err("--hmi-token: the token is empty".into());
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
            addr: a.parse().expect("an address"),
            token: token.map(str::to_string),
        };
        assert_eq!(at("127.0.0.1:8080", None).check(), Ok(()));
        assert_eq!(at("[::1]:8080", None).check(), Ok(()));
        assert!(
            at("0.0.0.0:8080", None)
                .check()
                .is_err_and(|e| e.contains("needs a token"))
        );
        assert_eq!(at("0.0.0.0:8080", Some("s3cret")).check(), Ok(()));
        assert!(
            at("127.0.0.1:8080", Some(" "))
                .check()
                .is_err_and(|e| e.contains("empty"))
        );
    }
}
