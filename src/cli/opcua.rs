//! `run`'s OPC UA options: from the command line to [`OpcUaOptions`].

use std::path::PathBuf;

use pkm_plc::services::opcua::{self, OpcUaOptions};

/// The OPC UA server a run asks for: `None` in unpaced virtual time (`unserved`) or with `--opcua none`; the next
/// ports tried when the default one is taken.
pub fn options(
    url: Option<&str>,
    users: Option<&PathBuf>,
    pki: Option<&PathBuf>,
    max_sessions: usize,
    virtual_time: bool,
) -> Result<Option<(OpcUaOptions, u16)>, String> {
    let (url, next_ports) = match (url, virtual_time) {
        (Some("none"), _) | (None, true) => {
            return match (users, pki) {
                (Some(_), _) | (_, Some(_)) => Err(format!(
                    "--opcua-users and --opcua-pki configure the OPC UA server, which {}",
                    if virtual_time {
                        "a --virtual run as fast as it goes does not serve"
                    } else {
                        "is off (--opcua none, or PKM_PLC_OPCUA=none in the environment)"
                    }
                )),
                (None, None) => Ok(None),
            };
        }
        (Some(_), true) => {
            return Err(
                "--opcua serves OPC UA in real time or in a paced simulation (--virtual --pace X); a --virtual run as fast as it goes has none".into(),
            );
        }
        (Some(url), false) => (url, 0),
        (None, false) => (opcua::DEFAULT_URL, DEFAULT_NEXT_PORTS),
    };
    let (addr, mut host) = opcua::parse_url(url)?;
    // Listening on every address: the endpoints announce this computer's name, which clients
    // elsewhere can reach, rather than 0.0.0.0.
    if addr.ip().is_unspecified() {
        host = opcua::server::host_name();
    }
    let users = users
        .map(|path| opcua::users::Users::load(path).map_err(|e| format!("--opcua-users {e}")))
        .transpose()?;
    let options = OpcUaOptions {
        addr,
        host,
        users,
        pki_dir: pki.cloned().unwrap_or_else(default_pki),
        pki_per_machine: pki.is_none(),
        max_sessions,
    };
    options.check()?;
    Ok(Some((options, next_ports)))
}

/// The next ports tried for the default endpoint when its port is taken (a second PLC on this
/// computer): 4841 … 4849, then any free one.
const DEFAULT_NEXT_PORTS: u16 = 9;

/// Where the default certificate stores are, one per machine in a directory of its name:
/// `$XDG_DATA_HOME/pkm-plc/opcua-pki`, else `~/.local/share/pkm-plc/opcua-pki`, else
/// `opcua-pki` here.
fn default_pki() -> PathBuf {
    let data = std::env::var_os("XDG_DATA_HOME")
        .filter(|d| !d.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".local/share")));
    match data {
        Some(d) => d.join("pkm-plc/opcua-pki"),
        None => PathBuf::from("opcua-pki"),
    }
}
