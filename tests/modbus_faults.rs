//! Link faults on Modbus TCP: garbage bytes, slow responses, exception responses and a station
//! that disappears and comes back. Each must become a bus fault (ERROR "bus fault", PWM zero),
//! never a hang or a panic; a returning station brings the link back.

mod common;

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::process::Command;
use std::time::Duration;

use common::stderr;

#[derive(Clone, Copy)]
enum Misbehaviour {
    Garbage,
    Slow,
    Exception,
}

/// A station that answers every request wrongly, on a free loopback port.
fn bad_station(how: Misbehaviour) -> u16 {
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
    let port = listener.local_addr().expect("address").port();
    std::thread::spawn(move || {
        for stream in listener.incoming().flatten() {
            std::thread::spawn(move || serve_badly(stream, how));
        }
    });
    port
}

fn serve_badly(mut s: TcpStream, how: Misbehaviour) {
    let mut header = [0u8; 7];
    loop {
        // MBAP header: transaction (2), protocol (2), length (2), unit (1); then the PDU.
        if s.read_exact(&mut header).is_err() {
            return;
        }
        let len = usize::from(u16::from_be_bytes([header[4], header[5]])).saturating_sub(1);
        let mut pdu = vec![0u8; len];
        if s.read_exact(&mut pdu).is_err() {
            return;
        }
        let reply: Vec<u8> = match how {
            Misbehaviour::Garbage => vec![0xde, 0xad, 0xbe, 0xef, 0x00, 0x01, 0x02, 0x03, 0xff],
            Misbehaviour::Slow => {
                std::thread::sleep(Duration::from_millis(500));
                continue;
            }
            Misbehaviour::Exception => {
                // Exception 4 (server device failure) for the request's function.
                vec![header[0], header[1], 0, 0, 0, 3, header[6], pdu[0] | 0x80, 4]
            }
        };
        if s.write_all(&reply).is_err() {
            return;
        }
    }
}

fn run_against(port: u16, seconds: &str) -> (serde_json::Value, String) {
    let dir = tempfile::tempdir().expect("tempdir");
    let summary = dir.path().join("s.json");
    let o = Command::new(env!("CARGO_BIN_EXE_pkm-plc"))
        .args(["run", "--bus", &format!("tcp:127.0.0.1:{port}"), "--duration", seconds])
        .args(["--summary", summary.to_str().expect("utf-8")])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env("RUST_LOG", "info")
        .output()
        .expect("run");
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let s = serde_json::from_str(&std::fs::read_to_string(&summary).expect("summary")).expect("json");
    (s, stderr(&o))
}

#[test]
fn garbage_slow_and_exceptional_stations_are_bus_faults() {
    for (how, name) in [
        (Misbehaviour::Garbage, "garbage"),
        (Misbehaviour::Slow, "slow"),
        (Misbehaviour::Exception, "exception"),
    ] {
        let (s, log) = run_against(bad_station(how), "2");
        assert_eq!(s["main"]["state"], "ERROR", "{name}: {s}");
        assert_eq!(s["main"]["error_reason"], "bus fault", "{name}");
        assert!(log.contains("bus fault after"), "{name}: {log}");
        let counts = log
            .lines()
            .find(|l| l.contains(" exchanges (tables)"))
            .expect("link report");
        let wanted = match how {
            Misbehaviour::Garbage => " disconnects",
            Misbehaviour::Slow => " timeouts",
            Misbehaviour::Exception => " exceptions",
        };
        let n: u64 = counts
            .split(", ")
            .chain(counts.split("; "))
            .find_map(|part| {
                part.strip_suffix(wanted)
                    .and_then(|p| p.rsplit(' ').next())
                    .and_then(|n| n.parse().ok())
            })
            .unwrap_or(0);
        assert!(n > 3, "{name}: {counts}");
    }
}

#[test]
fn the_link_comes_back_when_the_station_returns_but_error_stays_until_acknowledged() {
    let start = |port: u16| common::start_io_sim(&format!("127.0.0.1:{port}"), &[]);
    let (first, address) = start(0);
    let port = address.port();
    let restart = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(1500));
        drop(first); // the station disappears...
        std::thread::sleep(Duration::from_millis(1500));
        start(port).0 // ...and comes back on the same port
    });
    let (s, log) = run_against(port, "6");
    drop(restart.join().expect("restart"));
    assert!(log.contains("bus fault after"), "{log}");
    assert!(log.contains("the link works again"), "{log}");
    assert_eq!(s["main"]["state"], "ERROR");
    assert_eq!(s["main"]["error_reason"], "bus fault");
}
