//! io-sim's X20BC0087 as a client sees it, in-process: who feeds its watchdog, and registers a
//! client may name but that do not exist.

use std::borrow::Cow;
use std::time::{Duration, Instant};

use pkm_plc::services::io::x20bc0087::WATCHDOG_STATUS;
use pkm_plc::services::sim::modbus::Station;
use tokio_modbus::{ExceptionCode, Request, Response};

use crate::common;

/// The lab's TRIJOINT station: its map behind an X20BC0087 at node 1.
fn station() -> Station {
    let setup = pkm_plc::compose::Setup::new(common::loaded(&common::repo_config())).expect("trijoint");
    Station::bus_controller(setup.sim_bus(None).expect("the simulated machine"), 1)
}

/// Whether the bus controller's watchdog has expired (register 0x1042), as `client` reads it.
fn expired(station: &mut Station, client: u64) -> bool {
    match station.handle(Request::ReadHoldingRegisters(WATCHDOG_STATUS, 1), client) {
        Ok(Response::ReadHoldingRegisters(words)) => words == [1],
        other => panic!("the watchdog's status: {other:?}"),
    }
}

/// The PLC (client 1) writes once, then falls silent; a second client keeps trying to write
/// and reading. Its writes are refused (exception 6) and neither they nor its reads feed the
/// watchdog: it expires 50 ms after the PLC's last telegram, whatever the other client does.
/// (Before, every telegram fed it, and a refused client kept the outputs alive.)
#[test]
fn only_the_controlling_clients_telegrams_feed_the_x20bc0087_watchdog() {
    let mut station = station();
    station.set_watchdog(Some(Duration::from_millis(50)));
    let write = |value| Request::WriteSingleCoil(0, value);
    station.handle(write(false), 1).expect("the PLC's write");
    assert_eq!(station.owner(), Some(1));
    let silent = Instant::now();
    // Until it expires (then the outputs are zero and free, and writes are ignored until a
    // client resets the watchdog).
    while silent.elapsed() < Duration::from_millis(200) && !expired(&mut station, 2) {
        assert_eq!(station.handle(write(true), 2), Err(ExceptionCode::ServerDeviceBusy));
        station.watch();
        std::thread::sleep(Duration::from_millis(2));
    }
    station.watch();
    assert!(
        expired(&mut station, 2),
        "200 ms after the PLC's last telegram, with another client's every 2 ms, the watchdog of 50 ms has not expired"
    );
}

/// While the PLC is there, its own telegrams keep the watchdog from expiring.
#[test]
fn the_controlling_clients_telegrams_feed_the_x20bc0087_watchdog() {
    let mut station = station();
    station.set_watchdog(Some(Duration::from_millis(500)));
    let start = Instant::now();
    while start.elapsed() < Duration::from_millis(300) {
        station
            .handle(Request::WriteSingleCoil(0, false), 1)
            .expect("the PLC's write");
        station.watch();
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(!expired(&mut station, 1));
}

/// A write to the last register, or across it, is refused as an address that does not exist;
/// it used to overflow the register counter (a panic of the connection's task in a debug
/// build).
#[test]
fn a_write_at_register_0xffff_is_refused_as_an_illegal_address() {
    let mut station = station();
    assert_eq!(
        station.handle(Request::WriteSingleRegister(0xFFFF, 1), 1),
        Err(ExceptionCode::IllegalDataAddress)
    );
    assert_eq!(
        station.handle(Request::WriteMultipleRegisters(0xFFFE, Cow::Owned(vec![1, 2, 3])), 1),
        Err(ExceptionCode::IllegalDataAddress)
    );
    assert_eq!(
        station.handle(Request::ReadHoldingRegisters(0xFFFF, 2), 1).map(|_| ()),
        Err(ExceptionCode::IllegalDataAddress)
    );
}

/// A pn101 stepper told to run at once far beyond its pull-in speed falls out of step: the
/// station's report (what `io-sim` logs and writes with `--summary` when it stops) counts the
/// steps the module emitted that the motor did not make, and says where each carriage stands.
#[test]
fn the_stations_report_counts_the_steps_a_stepper_lost() {
    let dir = tempfile::tempdir().expect("tempdir");
    let config = common::machine_test_config(dir.path(), "pn101");
    let loaded = pkm_plc::runtime::config::load(Some(&config)).expect("pn101");
    let setup = pkm_plc::compose::Setup::new(loaded).expect("pn101");
    let bus = setup.sim_bus(None).expect("the simulated machine");
    let map = bus.io_map().clone();
    let mut station = Station::new(bus);
    // The register of the channel a variable is bound to.
    let address = |station: &Station, variable: &str| {
        let b = map
            .bindings
            .iter()
            .find(|b| b.variable == variable)
            .unwrap_or_else(|| panic!("{variable} in the map"));
        station
            .registers()
            .entries
            .iter()
            .find(|e| (e.module, e.channel) == (b.module, b.channel))
            .map(|e| e.address)
            .unwrap_or_else(|| panic!("{variable} in the register map"))
    };
    let at_rest = station.report();
    assert_eq!(at_rest.joints.len(), 3);
    assert!(
        at_rest
            .joints
            .iter()
            .all(|j| j.stepper && j.lost_steps == 0.0 && j.stalls == 0)
    );
    let (enable, speed) = (address(&station, "JOINT1_ENABLE"), address(&station, "JOINT1_SPEED"));
    station
        .handle(Request::WriteSingleCoil(enable, true), 1)
        .expect("enable");
    // 10 000 steps/s from rest: far beyond the pull-in speed of 2 mm/s.
    station
        .handle(Request::WriteSingleRegister(speed, 10_000), 1)
        .expect("speed");
    std::thread::sleep(Duration::from_millis(100));
    let report = station.report();
    let joint = report.joints[0];
    assert_eq!(joint.stalls, 1, "{report:?}");
    // The module emitted 10 000 steps/s for at least 0.1 s; the motor made none of them.
    assert!(joint.lost_steps >= 1000.0, "{report:?}");
    assert_eq!(joint.position_mm, at_rest.joints[0].position_mm, "{report:?}");
    assert!(report.joints[1..].iter().all(|j| j.lost_steps == 0.0), "{report:?}");
    let line = &report.lines()[0];
    assert!(line.starts_with("joint 1 at "), "{line}");
    assert!(line.ends_with("steps lost in 1 stalls"), "{line}");
}

/// A Modbus TCP frame: `id`, unit 0xFF, `pdu`.
fn frame(id: u16, pdu: &[u8]) -> Vec<u8> {
    let mut f = id.to_be_bytes().to_vec();
    f.extend([0, 0]);
    f.extend((pdu.len() as u16 + 1).to_be_bytes());
    f.push(0xFF);
    f.extend(pdu);
    f
}

/// Pipelined requests: a client that sends several requests before any answer (as the
/// soft-PLC's exchange does) gets every answer, in order, each under its own transaction id —
/// also when a request's bytes are split over two writes, and a malformed one among them is
/// answered with an exception without losing the ones around it.
#[test]
fn io_sims_tcp_station_answers_pipelined_requests_in_order() {
    use tokio::io::{AsyncReadExt as _, AsyncWriteExt as _};
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    runtime.block_on(async {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let address = listener.local_addr().expect("address");
        let server = pkm_plc::services::sim::server::serve_tcp(
            listener,
            station(),
            pkm_plc::services::sim::server::ServerOptions::default(),
            std::future::pending(),
        );
        let client = async {
            let mut s = tokio::net::TcpStream::connect(address).await.expect("connect");
            // Three reads in one write: inputs (12 of the DI's), the counters, the module table's
            // first status word; then a request of an unknown function, then a write split in two.
            let mut together = frame(7, &[0x02, 0, 0, 0, 12]);
            together.extend(frame(8, &[0x04, 0, 0, 0, 2]));
            together.extend(frame(9, &[0x03, 0xA0, 0x00, 0, 1]));
            together.extend(frame(10, &[0x2B, 0x0E, 0x01, 0x00]));
            let write = frame(11, &[0x05, 0, 0, 0, 0]);
            together.extend(&write[..9]);
            s.write_all(&together).await.expect("send");
            tokio::time::sleep(Duration::from_millis(20)).await;
            s.write_all(&write[9..]).await.expect("the rest");
            let mut got = Vec::new();
            let mut buf = [0u8; 512];
            let expected_len = [9 + 2, 9 + 4, 9 + 2, 9, 12].iter().sum::<usize>();
            while got.len() < expected_len {
                let n = tokio::time::timeout(Duration::from_secs(5), s.read(&mut buf))
                    .await
                    .expect("answers in time")
                    .expect("read");
                assert!(n > 0, "the station closed the connection: {got:02x?}");
                got.extend(&buf[..n]);
            }
            got
        };
        let got = tokio::select! {
            got = client => got,
            _ = server => panic!("the server ended"),
        };
        // The answers' transaction ids and function codes, frame by frame.
        let mut at = 0;
        let mut answers = Vec::new();
        while at + 7 <= got.len() {
            let len = usize::from(u16::from_be_bytes([got[at + 4], got[at + 5]]));
            answers.push((u16::from_be_bytes([got[at], got[at + 1]]), got[at + 7]));
            at += 6 + len;
        }
        assert_eq!(at, got.len(), "whole frames: {got:02x?}");
        assert_eq!(
            answers,
            [(7, 0x02), (8, 0x04), (9, 0x03), (10, 0x2B | 0x80), (11, 0x05)]
        );
    });
}
