//! Every machine over Modbus TCP, with both exchanges and every limit as shipped: io-sim serves
//! the machine's I/O map and plant, the soft-PLC references it, runs its shipped program to the
//! end from the operator's screen once READY, then jogs it. The positions are checked
//! ([`common::check_positions`]): the station's counters against the commanded positions at the
//! program's end, the machine's true joints (io-sim's `--summary`) against the PLC's last
//! reading, and no stepper may lose a step. Each machine's two exchanges (`tables`, `image`) run side by side,
//! each against a station of its own. The TRIJOINT's `tables` run talks to the station its map
//! names, the lab's X20BC0087; its `image` run to a generic station with the same modules (an
//! X20BC0087 has no packed image). Over the emulated RTU line: `tests/modbus_rtu.rs`.
//!
//! The steppers of pn101 and the O-X glide once lost every step over Modbus: their model judged a
//! set-point's change by the time since the station's last write, and a station writes the same
//! set-point several times a cycle (the coils, then the registers).

use std::path::Path;
use std::time::Duration;

use crate::common;

/// The longest referencing may take (pn101's, its joints one after another, takes about 40 s
/// with the test configuration on a quiet machine).
const READY_WITHIN: Duration = Duration::from_secs(150);

/// The longest a shipped program may take (the O-X glide's, 66.8 s planned, is the longest).
const PROGRAM_WITHIN: Duration = Duration::from_secs(150);

/// The longest a machine may take to stand still after a program or a jog (its regulators
/// settle within about 1.5 s).
const STILL_WITHIN: Duration = Duration::from_secs(10);

/// Sessions at once, over this module's tests: each is a PLC and a station, debug builds, beside
/// the other real-time tests; ten at once on two cores delayed the links' images by tens of
/// milliseconds and the screen's presses with them.
const SESSIONS_AT_ONCE: usize = 4;

/// The sessions' places.
static SESSIONS: common::Places = common::Places::new(SESSIONS_AT_ONCE);

/// One session: `machine` with `exchange` against a station of its own: READY, the shipped
/// program to its end, a jog along +x; the summary and the trace say how it went.
fn session(machine: &str, exchange: &str, dir: &Path) {
    let _place = SESSIONS.take();
    let config = common::machine_test_config(dir, machine);
    // The packed image needs the generic station (the TRIJOINT's is the lab's X20BC0087).
    if exchange == "image" {
        common::on_generic_station(&config);
    }
    let config = config.to_str().expect("utf-8");
    let station_summary = dir.join("station.json");
    let (mut sim, address) = common::start_io_sim(
        "127.0.0.1:0",
        &[
            "--config",
            config,
            "--summary",
            station_summary.to_str().expect("utf-8"),
        ],
    );
    let (s, t) = (dir.join("summary.json"), dir.join("trace.jsonl"));
    let mut command = common::pkm_command();
    command
        .args(["run", "--bus", &format!("tcp:{address}"), "--exchange", exchange])
        .args(["--config", config])
        .args(["--summary", s.to_str().expect("utf-8")])
        .args(["--trace", t.to_str().expect("utf-8")])
        .args(["--joystick", "none"])
        .env("RUST_LOG", "info");
    let what = format!("{machine} ({exchange})");
    let (mut run, url) = common::Logged::start(command, "operator screen at ", Duration::from_secs(60));
    // Referenced, the tool stands at the reference pose, where every shipped program starts:
    // the program first, then the jog (a program starts from the reference pose only).
    let ready = run.wait_for_state(0, "READY", READY_WITHIN);
    common::screen_command(&url, serde_json::json!({"cmd": "program", "what": "start"}));
    let started = run.wait_for_state(ready, "AUTO", Duration::from_secs(20));
    let ended = run.wait_for_state(started, "READY", PROGRAM_WITHIN);
    // The machine stands still at the program's end (where its positions are checked).
    assert!(
        common::screen_until_still(&url, STILL_WITHIN),
        "{what}: still moving {STILL_WITHIN:?} after the program's end"
    );
    common::screen_jog(&url, 1.0, 0.0, Duration::from_millis(1500));
    let moved = run.wait_for_state(ended, "MOTION", Duration::from_secs(10));
    run.wait_for_state(moved, "READY", Duration::from_secs(20));
    // And stands still after the jog, its regulators at rest, before the PLC stops.
    assert!(
        common::screen_until_still(&url, STILL_WITHIN),
        "{what}: still moving {STILL_WITHIN:?} after the jog"
    );
    assert!(run.terminate().success(), "{what}: {}", run.log());
    assert!(sim.stop().success(), "{what}: io-sim failed");
    let summary = common::read_json(&s);
    assert_eq!(summary["main"]["state"], "READY", "{what}: {summary}");
    assert_eq!(summary["program"]["completed"], true, "{what}: {summary}");
    // It ran its whole course: as long as planned (the overrides at 100 %, no hold).
    let ran = summary["program"]["duration_s"].as_f64().unwrap_or(0.0);
    let planned_s = summary["program"]["planned_s"].as_f64().unwrap_or(f64::INFINITY);
    assert!(
        ran >= planned_s * 0.99,
        "{what}: ran {ran} s of {planned_s} s planned: {summary}"
    );
    let trace = std::fs::read_to_string(&t).expect("trace");
    assert!(!trace.contains(r#""state":"ERROR""#), "{what}: an ERROR in the trace");
    let report = run
        .log()
        .lines()
        .find(|l| l.contains(&format!(" exchanges ({exchange})")))
        .map(str::to_string)
        .unwrap_or_else(|| panic!("{what}: no link report: {}", run.log()));
    let positions = common::check_positions(&what, &t, &common::read_json(&station_summary));
    eprintln!("{what}: program of {planned_s:.1} s ran {ran:.1} s; {positions}; {report}");
}

/// `machine` over both exchanges at once.
fn both_exchanges(machine: &str) {
    let dir = tempfile::tempdir().expect("tempdir");
    std::thread::scope(|scope| {
        for exchange in ["tables", "image"] {
            let dir = dir.path().join(exchange);
            std::fs::create_dir(&dir).expect("a directory");
            scope.spawn(move || {
                common::host::on_a_steady_host(&format!("{machine} ({exchange})"), || session(machine, exchange, &dir))
            });
        }
    });
}

#[test]
fn the_trijoint_references_jogs_and_runs_its_program_over_both_exchanges() {
    both_exchanges("trijoint");
}

#[test]
fn pn101_references_jogs_and_runs_its_program_over_both_exchanges() {
    both_exchanges("pn101");
}

#[test]
fn the_ox_x_glide_references_jogs_and_runs_its_program_over_both_exchanges() {
    both_exchanges("ox-x");
}

#[test]
fn the_ox_o_glide_references_jogs_and_runs_its_program_over_both_exchanges() {
    both_exchanges("ox-o");
}

#[test]
fn the_hexapod_references_jogs_and_runs_its_program_over_both_exchanges() {
    both_exchanges("hexapod");
}
