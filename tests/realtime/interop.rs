//! Interoperability with an independent Modbus implementation (pymodbus, from PyPI): its client
//! drives `pkm-plc io-sim`, and the soft-PLC runs against its server. pymodbus is installed into
//! a virtual environment under `target/` (never into the system's Python); where one cannot be
//! made (no `python3-venv`, no network), the tests say why on stderr and are skipped.

use crate::common;

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};

/// The virtual environment's Python (with pymodbus), made on first use; `Err`: why there is none.
fn python() -> Result<PathBuf, String> {
    common::python_interop().map_err(|e| format!("no pymodbus: {e}"))
}

fn script(name: &str) -> String {
    format!("{}/tests/interop/{name}", env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn a_pymodbus_client_drives_io_sim() {
    let python = match python() {
        Ok(p) => p,
        Err(why) => {
            common::skip("interop::a_pymodbus_client_drives_io_sim", &why);
            return;
        }
    };
    // The client pauses between writes longer than a controller would: no output watchdog. It
    // addresses the generic station's layout.
    let dir = tempfile::tempdir().expect("tempdir");
    let config = common::write_generic_station_config(dir.path());
    let config = config.to_str().expect("utf-8");
    let (sim, address) = common::start_io_sim("127.0.0.1:0", &["--watchdog-ms", "0", "--config", config]);
    let o = Command::new(&python)
        .arg(script("client.py"))
        .arg(address.to_string())
        .output()
        .expect("client.py");
    drop(sim);
    assert!(
        o.status.success(),
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert_eq!(String::from_utf8_lossy(&o.stdout), "ok\n");
}

#[test]
fn the_soft_plc_runs_against_a_pymodbus_server() {
    let python = match python() {
        Ok(p) => p,
        Err(why) => {
            common::skip("interop::the_soft_plc_runs_against_a_pymodbus_server", &why);
            return;
        }
    };
    // A free port (a small window for another process to take it: the server then cannot listen
    // and says so, or — another process listening there — never sees its probe and says that).
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("free port")
        .port();
    // The server waits up to 60 s for what it must see written: the run follows from there.
    let mut server = common::KillOnDrop(
        Command::new(&python)
            .arg(script("server.py"))
            .args([port.to_string(), "60".to_string()])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("server.py"),
    );
    let mut lines = BufReader::new(server.0.stdout.take().expect("stdout")).lines();
    // "ready": this server accepts connections.
    assert_eq!(lines.next().and_then(Result::ok).as_deref(), Some("ready"));
    // The server serves the generic station's layout.
    let dir = tempfile::tempdir().expect("tempdir");
    let config = common::write_config(dir.path(), "trijoint.json", &common::busy_machine_config());
    common::on_generic_station(&config);
    let mut command = common::pkm_command();
    command
        .args(["run", "--bus", &format!("tcp:127.0.0.1:{port}")])
        .args(["--config", config.to_str().expect("utf-8")])
        .env("RUST_LOG", "info");
    let (mut run, _) = common::Logged::start(command, "running in real time", std::time::Duration::from_secs(60));
    // The run goes on until the server saw what the soft-PLC writes at INIT (a busy machine's
    // first exchange may come late: no fixed window), then stops as an operator stops it.
    let verdict = lines.next().and_then(Result::ok);
    let status = run.terminate();
    let log = run.log();
    assert_eq!(verdict.as_deref(), Some("period 50"), "server: {verdict:?}\n{log}");
    assert!(server.0.wait().expect("server ends").success());
    assert_eq!(status.code(), Some(0), "{log}");
    // pymodbus's server answers only the first of requests sent together: the link goes on
    // with one request at a time, and says so.
    assert!(
        log.contains("the station answered only part of the requests sent together"),
        "{log}"
    );
}
