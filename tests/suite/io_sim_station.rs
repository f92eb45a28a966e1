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
