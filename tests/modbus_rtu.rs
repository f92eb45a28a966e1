//! Modbus RTU end to end over pseudo-terminals: the soft-PLC's driver on one end, the I/O
//! simulator's station on the other, joined by an emulated RS-485 line at 115 200 baud (frames
//! carried no faster than the baud rate, silent intervals kept), the TRIJOINT application running
//! in real time — referencing (fast, with the real-time test configuration: about 17 s over this
//! line) and a jog by direction button (pressed at 19 s, and again at 27 s for a busy machine,
//! where referencing may end late); the run ends when the jog has moved the machine and it stands
//! again (about 20 s), at the latest after `common::JOG_RUN_S` (32 s).
//! The driver's default exchange on a serial line is the packed image, one transaction per
//! exchange.
//!
//! A binary of its own, so that it runs alone: the station's plant runs on the wall clock and the
//! line's timing is emulated by threads of this process, and beside the other real-time tests
//! (tests/realtime/, eight at a time) the line's exchanges came too late for the drives' encoders
//! and referencing.

#[path = "common/mod.rs"]
mod common;

use pkm_plc::io::line::LineTiming;
use pkm_plc::io::modbus::{ExchangeMode, ModbusBus, Transport};
use pkm_plc::plc::Plc;
use pkm_plc::run::{self, RealTimeOptions};
use pkm_plc::sim::modbus::{Station, StationOnLine};

#[test]
fn the_application_runs_over_modbus_rtu_on_a_pty_pair() {
    // This tests the exchange, not the scheduler's timing: fast referencing, late cycles logged.
    let loaded = common::loaded(&common::realtime_config());
    // The station's panel presses the direction button "right" after referencing.
    let dir = tempfile::tempdir().expect("tempdir");
    let scenario = common::jog_right_at(dir.path(), &common::JOG_PRESSES_S);
    let setup = pkm_plc::compose::Setup::new(loaded.clone()).expect("known machine");
    let station = Station::new(setup.sim_bus(Some(&scenario)).expect("sim"));
    // This tests the exchange, not its timing: the station's watchdog waits longer than a busy
    // machine may stall the test's threads.
    let relaxed = pkm_plc::sim::server::ServerOptions {
        watchdog: Some(std::time::Duration::from_secs(1)),
        ..Default::default()
    };
    let (_station, plc_end) =
        StationOnLine::start(station, LineTiming::modbus_rtu(115_200), relaxed).expect("station on the line");
    let map = setup.io_map().expect("valid map").expect("an io_map");
    // This tests the exchange, not its timing: a busy machine may delay an image, and slow the
    // emulated line's exchanges beyond what the regulators are tuned for.
    let link = pkm_plc::io::modbus::ModbusOptions {
        max_input_age: std::time::Duration::from_millis(500),
        max_exchange: std::time::Duration::from_millis(100),
        ..Default::default()
    };
    let bus = ModbusBus::new(map, Transport::Port(Some(plc_end)), link).expect("the image fits");
    assert_eq!(bus.exchange(), ExchangeMode::Image);
    let mut plc = Plc::build(&loaded.config, &pkm_plc::machines::all_programs(), Box::new(bus)).expect("valid");
    let trace = dir.path().join("trace.jsonl");
    let digest = setup.digest().expect("digest");
    plc.set_recorder(Box::new(
        pkm_plc::trace::record::Recorder::create(&trace, &plc, &digest).expect("trace"),
    ));
    let options = RealTimeOptions {
        source: Default::default(),
        // As `run` does: the cycles ahead of the other tests' processes where the test may
        // (root, CAP_SYS_NICE); elsewhere a warning and normal scheduling.
        realtime_priority: 80,
        lock_memory: false,
        spin_ns: 0,
        duration_ns: Some((common::JOG_RUN_S * 1e9) as u64),
    };
    let started = std::time::Instant::now();
    let run = run::start_realtime(plc, options).expect("real-time run");
    // The run ends once the jog has moved the machine and it stands again (READY after MOTION):
    // on a quiet machine after the first press, about 11 s before `JOG_RUN_S`, which still
    // bounds it (the second press is for a busy machine, where referencing ends late). The
    // snapshot is refreshed ten times a second; a jog's MOTION lasts over a second.
    let snapshot = run.snapshot();
    let mut moved = false;
    while !run.is_finished() {
        let state = snapshot.lock().unwrap_or_else(|p| p.into_inner()).state.clone();
        moved |= state == "MOTION";
        if moved && state == "READY" {
            run.stop();
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    let mut outcome = run.join().expect("real-time run");
    if let Some(recorder) = outcome.plc.take_recorder() {
        recorder.finish().expect("trace written");
    }
    let status = outcome.plc.app_status().expect("status");
    // Referenced (about 17 s over this line: the approaches wait for inputs) and jogged by the direction button, without a bus fault or other error.
    assert_eq!((status.state, status.reason), ("READY", None));
    let trace = std::fs::read_to_string(&trace).expect("trace");
    assert!(trace.contains(r#""state":"MOTION""#), "no MOTION in the trace");
    assert!(!trace.contains(r#""state":"ERROR""#), "an ERROR in the trace");
    let bus = outcome
        .plc
        .bus()
        .as_any()
        .downcast_ref::<ModbusBus>()
        .expect("the Modbus bus");
    let stats = bus.stats();
    let exchanges = stats.exchanges.load(std::sync::atomic::Ordering::Relaxed);
    // About 7 ms an exchange at 115 200 baud, 144 a second: more than half of that, as before
    // (2500 in 32 s), whenever the jog ended.
    let run_s = started.elapsed().as_secs_f64();
    assert!(exchanges as f64 > 78.0 * run_s, "{exchanges} exchanges in {run_s:.1} s");
    assert_eq!(stats.timeouts.load(std::sync::atomic::Ordering::Relaxed), 0);
    let mean_us = stats.exchange_ns_total.load(std::sync::atomic::Ordering::Relaxed) as f64 / exchanges as f64 / 1e3;
    eprintln!("RTU at 115 200 baud (emulated line): {exchanges} exchanges in {run_s:.1} s, mean {mean_us:.0} µs");
}
