//! `pkm-plc station scan tcp:HOST[:PORT]`: what an X20BC0087 says about itself and its modules,
//! read-only, and with `--write-map FILE` an I/O map skeleton for what it holds — the first
//! thing a lab does with the real station.

use std::fmt::Write as _;
use std::net::{SocketAddr, ToSocketAddrs};
use std::path::Path;
use std::time::Duration;

use super::Failure;
use super::args::{StationArgs, StationOp};
use pkm_plc::services::io::catalogue;
use pkm_plc::services::io::map::DEFAULT_WATCHDOG_MS;
use pkm_plc::services::io::x20bc0087::client::{Identity, Registers};
use pkm_plc::services::io::x20bc0087::{ModuleRecord, NO_DATA, SIMULATED_UNPINNED_ID, show_index, type_name};

/// The Modbus TCP port a bus controller listens on unless set otherwise.
pub const DEFAULT_PORT: u16 = 502;

/// Why a scan failed.
#[derive(Debug, thiserror::Error)]
pub enum ScanError {
    /// The address is not `tcp:HOST[:PORT]`.
    #[error("\"{0}\" is not tcp:HOST[:PORT]")]
    Address(String),
    /// No connection.
    #[error("cannot connect to {address}: {cause}")]
    Connect {
        /// Where.
        address: SocketAddr,
        /// Why.
        cause: String,
    },
    /// A request failed.
    #[error("{address}: {source} (is it an X20BC0087?)")]
    Request {
        /// Where.
        address: SocketAddr,
        /// The request and why.
        source: pkm_plc::services::io::x20bc0087::client::RequestError,
    },
    /// The runtime could not start.
    #[error("cannot start the tokio runtime: {0}")]
    Runtime(std::io::Error),
}

/// What a scan read.
#[derive(Clone, Debug)]
pub struct Scan {
    /// The station's address.
    pub address: SocketAddr,
    /// Its own registers.
    pub identity: Identity,
    /// Its module table, in slot order.
    pub modules: Vec<ModuleRecord>,
}

/// `tcp:HOST[:PORT]` (port 502 when not given) as an address.
pub fn parse_address(s: &str) -> Result<SocketAddr, ScanError> {
    let rest = s.strip_prefix("tcp:").ok_or_else(|| ScanError::Address(s.into()))?;
    let with_port = if rest.rsplit_once(':').is_some_and(|(_, p)| p.parse::<u16>().is_ok()) && !rest.ends_with(']') {
        rest.to_string()
    } else {
        format!("{rest}:{DEFAULT_PORT}")
    };
    with_port
        .to_socket_addrs()
        .ok()
        .and_then(|mut a| a.next())
        .ok_or_else(|| ScanError::Address(s.into()))
}

/// Reads the station at `address`: only reads, each request within `timeout`.
pub fn scan(address: SocketAddr, timeout: Duration) -> Result<Scan, ScanError> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(ScanError::Runtime)?;
    runtime.block_on(async {
        let connect = tokio::time::timeout(timeout, tokio::net::TcpStream::connect(address)).await;
        let stream = match connect {
            Ok(Ok(stream)) => stream,
            Ok(Err(e)) => {
                return Err(ScanError::Connect {
                    address,
                    cause: e.to_string(),
                });
            }
            Err(_) => {
                return Err(ScanError::Connect {
                    address,
                    cause: format!("no connection within {} ms", timeout.as_millis()),
                });
            }
        };
        let mut ctx = tokio_modbus::client::tcp::attach(stream);
        let mut registers = Registers::new(&mut ctx, timeout);
        let failed = |source| ScanError::Request { address, source };
        let identity = registers.identity().await.map_err(failed)?;
        let modules = registers.module_table().await.map_err(failed)?;
        Ok(Scan {
            address,
            identity,
            modules,
        })
    })
}

fn dotted(b: [u8; 4]) -> String {
    format!("{}.{}.{}.{}", b[0], b[1], b[2], b[3])
}

impl Scan {
    /// The report for people.
    pub fn report(&self) -> String {
        let id = &self.identity;
        let mut out = String::new();
        let _ = writeln!(out, "X20BC0087 at {} (node {})", self.address, id.node);
        let mac: Vec<String> = id.mac.iter().map(|b| format!("{b:02x}")).collect();
        let _ = writeln!(
            out,
            "  network: MAC {}, IP {} (in flash {}), subnet {}, gateway {}, Modbus port {}",
            mac.join(":"),
            dotted(id.ip_current),
            dotted(id.ip_flash),
            dotted(id.subnet),
            dotted(id.gateway),
            id.port
        );
        let _ = writeln!(
            out,
            "  product: serial {}, product code {:#06X}, hardware variant {} version {}, firmware {}.{}",
            id.serial, id.product_code, id.hw_variant, id.hw_version, id.firmware.0, id.firmware.1
        );
        let w = &id.watchdog;
        let state = if w.status != 0 { "EXPIRED" } else { "running" };
        let _ = writeln!(
            out,
            "  watchdog: {} ms, {}, {state} ({} ms since its last reset)",
            w.threshold_ms,
            w.mode_name(),
            w.elapsed_ms
        );
        let _ = writeln!(out, "  status {:#06x}, errors: {}", id.status, id.errors);
        let [ai, ao, di, dout] = id.process;
        let _ = writeln!(
            out,
            "  process data: {} modules; analog in {} modules {} B, analog out {} modules {} B, digital in {} modules \
             {} B, digital out {} modules {} B",
            id.modules, ai.0, ai.1, ao.0, ao.1, di.0, di.1, dout.0, dout.1
        );
        let _ = writeln!(
            out,
            "  X2X: cycle {} µs, {} cycles, {} bus-off, {} sync errors, {} frame errors; {} Modbus client(s) connected",
            id.x2x_cycle_us, id.x2x_cycles, id.x2x_errors[0], id.x2x_errors[1], id.x2x_errors[2], id.clients
        );
        let _ = writeln!(
            out,
            "{:>4}  {:<7} {:<22} {:>10}  {:<9} {:>5}  {:>9} {:>10} {:>10} {:>11}",
            "slot",
            "ID",
            "module",
            "serial",
            "config ID",
            "model",
            "analog in",
            "analog out",
            "digital in",
            "digital out"
        );
        for (i, m) in self.modules.iter().enumerate() {
            let configured = if m.configured_id == 0 {
                "-".to_string()
            } else {
                format!("{:#06X}", m.configured_id)
            };
            let _ = writeln!(
                out,
                "{:>4}  {:<7} {:<22} {:>10}  {:<9} {:>5}  {:>9} {:>10} {:>10} {:>11}",
                i + 1,
                format!("{:#06X}", m.id),
                type_name(m.id),
                m.serial,
                configured,
                m.function_model,
                show_index(m.analog_in),
                show_index(m.analog_out),
                show_index(m.digital_in),
                show_index(m.digital_out)
            );
        }
        if self.modules.is_empty() {
            out.push_str("  no modules in the module table\n");
        }
        out
    }

    /// Where the station's answers contradict each other — its module count and its module
    /// table, a module's data beyond the byte counts the station reports, analog data at an odd
    /// byte, two modules of one serial number — one line each: a faulty or lying station, whose
    /// table is no ground for a map.
    pub fn doubts(&self) -> Vec<String> {
        let mut doubts = Vec::new();
        let id = &self.identity;
        if usize::from(id.modules) != self.modules.len() {
            doubts.push(format!(
                "the station says it holds {} modules (register 0x1100), its module table lists {}",
                id.modules,
                self.modules.len()
            ));
        }
        let [ai, ao, di, dout] = id.process;
        let kinds = [
            ("analog input", ai.1, true),
            ("analog output", ao.1, true),
            ("digital input", di.1, false),
            ("digital output", dout.1, false),
        ];
        for (i, m) in self.modules.iter().enumerate() {
            let indexes = [m.analog_in, m.analog_out, m.digital_in, m.digital_out];
            for (&index, &(what, bytes, analog)) in indexes.iter().zip(&kinds) {
                if index == NO_DATA {
                    continue;
                }
                if index >= bytes {
                    doubts.push(format!(
                        "slot {}: its {what} data at byte {index} lies beyond the {bytes} bytes of {what}s the station reports",
                        i + 1
                    ));
                }
                if analog && index % 2 != 0 {
                    doubts.push(format!(
                        "slot {}: its {what} data at byte {index}, which is odd: registers are two bytes each",
                        i + 1
                    ));
                }
            }
            if let Some(j) = self.modules[..i]
                .iter()
                .position(|o| o.serial == m.serial && m.serial != 0)
            {
                doubts.push(format!(
                    "slots {} and {} report the same serial number, {}",
                    j + 1,
                    i + 1,
                    m.serial
                ));
            }
        }
        doubts
    }

    /// An I/O map skeleton for what the station holds: the station, its watchdog, and each
    /// module in its slot with its ID pinned; a module of an ID the catalogue does not know gets
    /// a type to be written by hand (the map is refused until it is). No bindings.
    pub fn map_skeleton(&self) -> serde_json::Value {
        let modules: Vec<serde_json::Value> = self
            .modules
            .iter()
            .enumerate()
            .map(|(i, m)| {
                let slot = i + 1;
                let (name, ty) = match catalogue::by_hardware_id(m.id) {
                    Some(t) => (format!("{}_{slot}", &t.name[3..]), t.name.to_string()),
                    // io-sim's stand-in for an unpinned ID: no ID to pin, the type to write.
                    None if m.id == SIMULATED_UNPINNED_ID => {
                        let ty = "unknown: io-sim's map does not pin this module's ID; write its type";
                        return serde_json::json!({"name": format!("SLOT{slot}"), "type": ty, "slot": slot});
                    }
                    None => (
                        format!("SLOT{slot}"),
                        format!(
                            "unknown ID {:#06X}: write its type (pkm-plc's catalogue: see docs/hardware.md)",
                            m.id
                        ),
                    ),
                };
                serde_json::json!({"name": name, "type": ty, "slot": slot, "id": format!("{:#06X}", m.id)})
            })
            .collect();
        serde_json::json!({
            "station": "X20BC0087",
            "watchdog_ms": DEFAULT_WATCHDOG_MS,
            "modules": modules,
            "bindings": [],
        })
    }
}

/// Writes `map` to `path`, which must not exist yet (a lab's map is not overwritten by a scan).
pub fn write_map(path: &Path, map: &serde_json::Value) -> Result<(), String> {
    let text = serde_json::to_string_pretty(map).map_err(|e| e.to_string())? + "\n";
    let mut file = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(path)
        .map_err(|e| match e.kind() {
            std::io::ErrorKind::AlreadyExists => {
                format!(
                    "{}: exists already; the scan does not overwrite a map: remove it or name another file",
                    path.display()
                )
            }
            _ => format!("{}: {e}", path.display()),
        })?;
    std::io::Write::write_all(&mut file, text.as_bytes()).map_err(|e| format!("{}: {e}", path.display()))
}

/// The `station` subcommand: runs it as `args` ask and prints its report.
pub fn command(args: StationArgs) -> Result<(), Failure> {
    let StationOp::Scan {
        address,
        write_map,
        timeout_ms,
    } = args.op;
    let address = parse_address(&address).map_err(|e| Failure::usage(e.to_string()))?;
    let scan = scan(address, Duration::from_millis(timeout_ms)).map_err(|e| Failure::run(e.to_string()))?;
    print!("{}", scan.report());
    let doubts = scan.doubts();
    for doubt in &doubts {
        eprintln!("warning: station {address}: {doubt}");
    }
    if let Some(path) = write_map {
        if !doubts.is_empty() {
            return Err(Failure::run(format!(
                "{}: not written: the station's answers contradict each other ({}), so its module table is no ground for \
                 a map; check the station (its power, its X2X link, its firmware) and scan again",
                path.display(),
                doubts.join("; ")
            )));
        }
        self::write_map(&path, &scan.map_skeleton()).map_err(Failure::run)?;
        println!(
            "I/O map skeleton for {} modules written to {}: add the bindings, name any module of an unknown ID",
            scan.modules.len(),
            path.display()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_take_port_502_unless_given() {
        assert_eq!(parse_address("tcp:127.0.0.1").expect("valid").port(), 502);
        assert_eq!(parse_address("tcp:127.0.0.1:5021").expect("valid").port(), 5021);
        assert_eq!(parse_address("tcp:[::1]").expect("valid").port(), 502);
        assert_eq!(parse_address("tcp:[::1]:7").expect("valid").port(), 7);
        assert!(matches!(parse_address("udp:127.0.0.1"), Err(ScanError::Address(_))));
    }
}
