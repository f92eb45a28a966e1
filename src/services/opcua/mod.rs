//! The OPC UA server: how a lab's SCADA, a teaching dashboard or an MES reads the
//! machine and, with credentials, commands it — as a B&R Automation Runtime controller serves
//! its variables.
//!
//! - [`space`]: the address space: the machine, its state, its task classes and every
//!   process-image variable with its IEC type and unit; the commands as methods.
//! - [`server`]: the server on the runtime's tokio runtime, fed by the same published frames as
//!   the operator's screen (off the cyclic thread), its commands entering the process image
//!   through the screen's [`crate::services::hmi::commands::CommandSink`] — traced and replayed like the
//!   screen's.
//! - [`nodes`]: the node manager: the nodes in memory, the methods called with the session's
//!   user.
//! - [`conditions`], [`alarm_events`]: alarms and conditions: what goes wrong, as events a
//!   SCADA subscribes to and acknowledges; [`emitters`]: where their events are emitted.
//! - [`companion`]: OPC 40001-1 Machinery: the machine in the `Machines` folder, its
//!   nameplate and its Machinery states.
//! - [`machine_tool`]: OPC 40501-1 Machine Tools: the machine typed `MachineToolType`, its
//!   channel, spindle, program, job, messages, prognoses and tools.
//! - [`auth`]: anonymous sessions read; users of the users file ([`users`]) also command.
//! - [`units`]: engineering units from the variables' names.
//! - [`ranges`]: their EURange, where the configuration or the PLC bounds them.
//! - [`gate`]: the bound on connections held at once.
//! - [`history`]: the main variables' last ten minutes, for HistoryRead.
//!
//! Loopback only by default. Beyond it the server needs a users file and offers only the
//! signed and encrypted endpoints (Basic256Sha256); the unsecured endpoint is offered on
//! loopback only.

pub mod alarm_events;
pub mod alarm_methods;
pub mod auth;
pub mod companion;
pub mod conditions;
pub mod emitters;
pub mod gate;
pub mod history;
pub mod machine_tool;
pub mod methods;
pub mod nodes;
pub mod ranges;
pub mod server;
pub mod space;
pub mod units;
pub mod users;

use std::net::{IpAddr, SocketAddr, ToSocketAddrs};
use std::path::PathBuf;

/// The default endpoint: loopback, OPC UA's registered port.
pub const DEFAULT_URL: &str = "opc.tcp://127.0.0.1:4840";

/// The default bound on sessions: a Node-RED flow opens a connection and a session per OPC UA
/// node, and a SCADA gateway's clients all come from one computer.
pub const DEFAULT_MAX_SESSIONS: usize = 100;

/// Of `max_sessions`, how many may be anonymous (or not activated yet) at once: three quarters;
/// the rest are kept for users, whose sessions then need not close another's.
pub fn max_not_users(max_sessions: usize) -> usize {
    (max_sessions - max_sessions / 4).max(1)
}

/// How many connections the port holds for `max_sessions`: a tenth more (at least 4), for clients
/// that only ask for the endpoints and for one opening a session while another closes.
pub fn max_connections(max_sessions: usize) -> usize {
    max_sessions + (max_sessions / 10).max(4)
}

/// Where and how the server is served.
#[derive(Clone, Debug)]
pub struct OpcUaOptions {
    /// The address to listen on.
    pub addr: SocketAddr,
    /// The host name the endpoints are announced with (as the user wrote it in the URL).
    pub host: String,
    /// Who may command; `None`: nobody (read-only).
    pub users: Option<users::Users>,
    /// The server's certificate and key, and the clients' trusted and rejected certificates.
    pub pki_dir: PathBuf,
    /// Whether `pki_dir` holds a store per machine (the default store: each machine's in a
    /// directory of its name, so that each has a certificate of its own and a client trusted
    /// for one is not trusted for the others) rather than being the store itself (as
    /// `--opcua-pki` names it).
    pub pki_per_machine: bool,
    /// Sessions at once.
    pub max_sessions: usize,
}

/// Parses `opc.tcp://HOST:PORT` (a trailing `/` is allowed): the address to listen on and the host
/// name to announce.
pub fn parse_url(url: &str) -> Result<(SocketAddr, String), String> {
    let bad = |why: &str| {
        format!(
            "--opcua {}: {why} (e.g. {DEFAULT_URL}, opc.tcp://0.0.0.0:4840)",
            crate::runtime::config::shorten(url)
        )
    };
    let rest = url
        .strip_prefix("opc.tcp://")
        .ok_or_else(|| bad("an OPC UA endpoint is opc.tcp://HOST:PORT"))?;
    let rest = rest.strip_suffix('/').unwrap_or(rest);
    if rest.contains('/') {
        return Err(bad("the server has one endpoint path, the root: give no path"));
    }
    let (host, port) = rest.rsplit_once(':').ok_or_else(|| bad("the port is missing"))?;
    let port: u16 = port.parse().map_err(|_| bad("the port is not a number 0 … 65535"))?;
    let bare = host.trim_start_matches('[').trim_end_matches(']');
    let ip = match bare.parse::<IpAddr>() {
        Ok(ip) => ip,
        Err(_) if bare == "localhost" => IpAddr::from([127, 0, 0, 1]),
        Err(_) => (bare, port)
            .to_socket_addrs()
            .ok()
            .and_then(|mut a| a.next())
            .map(|a| a.ip())
            .ok_or_else(|| bad("the host is not an IP address or a name this computer resolves"))?,
    };
    Ok((SocketAddr::new(ip, port), bare.to_string()))
}

impl OpcUaOptions {
    /// Refuses what must not be served: another address than loopback without users (anyone who
    /// reaches the port would read the machine over an unauthenticated, unencrypted link, and
    /// nobody could command), a bound of zero sessions.
    pub fn check(&self) -> Result<(), String> {
        if self.max_sessions == 0 {
            return Err("--opcua-max-sessions: at least 1".into());
        }
        if !self.addr.ip().is_loopback() && self.users.is_none() {
            return Err(format!(
                "--opcua {}: serving OPC UA beyond this computer needs users who may command (--opcua-users FILE): \
                 without them the server would be open to anyone who reaches the port",
                self.addr
            ));
        }
        Ok(())
    }

    /// The certificate store of `machine`'s server.
    pub fn pki_of(&self, machine: &str) -> PathBuf {
        if self.pki_per_machine {
            // A directory name whatever the machine's name holds.
            let name: String = machine
                .chars()
                .map(|c| {
                    if c.is_ascii_alphanumeric() || "-_.".contains(c) {
                        c
                    } else {
                        '_'
                    }
                })
                .collect();
            self.pki_dir.join(name.trim_start_matches('.'))
        } else {
            self.pki_dir.clone()
        }
    }

    /// Whether the server is reached from this computer only.
    pub fn loopback(&self) -> bool {
        self.addr.ip().is_loopback()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_endpoint_url_is_parsed_or_refused_with_why() {
        assert_eq!(
            parse_url("opc.tcp://127.0.0.1:4840"),
            Ok(("127.0.0.1:4840".parse().expect("addr"), "127.0.0.1".into()))
        );
        assert_eq!(
            parse_url("opc.tcp://localhost:4841/"),
            Ok(("127.0.0.1:4841".parse().expect("addr"), "localhost".into()))
        );
        assert_eq!(
            parse_url("opc.tcp://[::1]:4840"),
            Ok(("[::1]:4840".parse().expect("addr"), "::1".into()))
        );
        assert_eq!(
            parse_url("http://127.0.0.1:4840"),
            Err("--opcua http://127.0.0.1:4840: an OPC UA endpoint is opc.tcp://HOST:PORT (e.g. opc.tcp://127.0.0.1:4840, opc.tcp://0.0.0.0:4840)".into())
        );
        assert!(parse_url("opc.tcp://127.0.0.1").is_err_and(|e| e.contains("the port is missing")));
        assert!(parse_url("opc.tcp://127.0.0.1:99999").is_err_and(|e| e.contains("not a number")));
        assert!(parse_url("opc.tcp://127.0.0.1:4840/pkm").is_err_and(|e| e.contains("give no path")));
    }

    #[test]
    fn only_loopback_goes_without_users() {
        let at = |url: &str, users: Option<users::Users>| {
            let (addr, host) = parse_url(url).expect("url");
            OpcUaOptions {
                addr,
                host,
                users,
                pki_dir: PathBuf::from("pki"),
                pki_per_machine: false,
                max_sessions: DEFAULT_MAX_SESSIONS,
            }
        };
        assert_eq!(at("opc.tcp://127.0.0.1:4840", None).check(), Ok(()));
        assert_eq!(
            at("opc.tcp://0.0.0.0:4840", None).check(),
            Err("--opcua 0.0.0.0:4840: serving OPC UA beyond this computer needs users who may command (--opcua-users FILE): without them the server would be open to anyone who reaches the port".into())
        );
        let users = users::Users {
            users: vec![users::User {
                name: "operator".into(),
                credential: users::Credential::Password("a-long-passphrase".into()),
            }],
            origin: PathBuf::from("users.json"),
        };
        assert_eq!(at("opc.tcp://0.0.0.0:4840", Some(users)).check(), Ok(()));
    }
}
