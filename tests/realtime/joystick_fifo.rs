//! End to end, in real time: `pkm-plc run --joystick FIFO` on the simulated machine, fed a
//! fabricated raw event capture (the documented 24-byte `struct input_event` layout) through a
//! FIFO. Once READY (about 15 s with the fast-referencing test configuration; the script's
//! times count from there) the stick goes full right — M moves in +x — then the writer
//! closes the FIFO in the middle of the motion (an unplugged device): axes at zero, a warning,
//! READY. The writer comes back and pulls the stick towards the operator — M moves down. The
//! trace of the run replays identically. The run takes about 29 s.

use crate::common;

use std::collections::HashMap;
use std::io::Write;
use std::process::Command;
use std::time::{Duration, Instant};

use pkm_plc::services::io::joystick::InputEvent;
use pkm_plc::services::io::joystick::codes::*;

fn report(axis: u16, value: i32) -> Vec<u8> {
    [
        InputEvent {
            time_us: 0,
            kind: EV_ABS,
            code: axis,
            value,
        }
        .to_bytes(),
        InputEvent {
            time_us: 0,
            kind: EV_SYN,
            code: SYN_REPORT,
            value: 0,
        }
        .to_bytes(),
    ]
    .concat()
}

fn sleep_until(start: Instant, s: f64) {
    std::thread::sleep((start + Duration::from_secs_f64(s)).saturating_duration_since(Instant::now()));
}

/// One main-class record of the trace with the values known at that cycle.
struct Cycle {
    t_s: f64,
    state: String,
    values: HashMap<String, serde_json::Value>,
}

/// The main class's cycles: every variable's value at each, from the trace's deltas.
fn main_cycles(trace: &str) -> Vec<Cycle> {
    let mut values = HashMap::new();
    let mut cycles = Vec::new();
    for line in trace.lines().skip(1) {
        let r: serde_json::Value = serde_json::from_str(line).expect("a trace record");
        if r["task"] != "main" {
            continue;
        }
        for part in ["in", "out"] {
            if let Some(o) = r[part].as_object() {
                for (k, v) in o {
                    values.insert(k.clone(), v.clone());
                }
            }
        }
        cycles.push(Cycle {
            t_s: r["t_us"].as_f64().expect("t_us") / 1e6,
            state: r["state"].as_str().expect("state").to_string(),
            values: values.clone(),
        });
    }
    cycles
}

#[test]
fn a_capture_through_a_fifo_drives_m_and_an_unplug_stops_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let fifo = dir.path().join("joystick");
    let made = Command::new("mkfifo").arg(&fifo).status().expect("mkfifo runs");
    assert!(made.success(), "mkfifo");
    let trace = dir.path().join("trace.jsonl");
    let config = common::write_realtime_config(dir.path());
    let mut command = common::pkm_command();
    command
        .args(["run", "--config", config.to_str().expect("utf-8"), "--joystick"])
        .arg(&fifo)
        .arg("--trace")
        .arg(&trace)
        .env("RUST_LOG", "info");
    let (mut run, _) = common::Logged::start(command, "running in real time", Duration::from_secs(30));
    // The script's times, from READY (about `FAST_READY_S` after the start; later on a busy
    // machine), as in the comments below.
    run.wait_for_state(0, "READY", Duration::from_secs(90));
    let ready = Instant::now();

    // Full right 2.4 s after READY.
    sleep_until(ready, 2.4);
    let mut writer = std::fs::OpenOptions::new()
        .write(true)
        .open(&fifo)
        .expect("open the FIFO");
    writer.write_all(&report(ABS_X, 32767)).expect("write");
    // Unplugged in the middle of the motion.
    sleep_until(ready, 5.4);
    drop(writer);
    // Back, and pulled towards the operator (raw y positive; inverted by default: M moves down).
    sleep_until(ready, 6.9);
    let mut writer = std::fs::OpenOptions::new()
        .write(true)
        .open(&fifo)
        .expect("reopen the FIFO");
    writer.write_all(&report(ABS_Y, 32767)).expect("write");
    sleep_until(ready, 8.9);
    writer.write_all(&report(ABS_Y, 0)).expect("write");
    // The tool brakes and stands; the run ends 13.4 s after READY.
    sleep_until(ready, 13.4);
    let status = run.terminate();
    let log = run.log();
    assert!(status.success(), "{log}");
    assert!(log.contains("joystick: reading FIFO"), "{log}");
    assert!(
        log.contains("the writer closed it: disconnected, axes at zero"),
        "{log}"
    );
    if let Some(line) = log.lines().find(|l| l.contains("reports taken into the process image")) {
        eprintln!("{line}");
    }

    let cycles = main_cycles(&std::fs::read_to_string(&trace).expect("trace"));
    let value = |c: &Cycle, n: &str| c.values.get(n).and_then(serde_json::Value::as_f64).unwrap_or(f64::NAN);
    let flag = |c: &Cycle, n: &str| c.values.get(n).and_then(serde_json::Value::as_bool);
    // Full right: MOTION in the cycle that latched it, M moves in +x.
    let right = cycles
        .iter()
        .position(|c| value(c, "JOYSTICK_X") == 1.0)
        .expect("the deflection reached the process image");
    assert_eq!(cycles[right].state, "MOTION", "at {} s", cycles[right].t_s);
    assert!(cycles[right - 1].t_s >= common::FAST_READY_S, "referenced first");
    // Unplugged: READY in the cycle that saw it, after M went at least 10 mm right.
    let unplugged = right
        + cycles[right..]
            .iter()
            .position(|c| flag(c, "JOYSTICK_CONNECTED") == Some(false))
            .expect("the unplug reached the process image");
    let c = &cycles[unplugged];
    assert_eq!(
        (c.state.as_str(), value(c, "JOYSTICK_X")),
        ("READY", 0.0),
        "at {} s",
        c.t_s
    );
    let dx = value(c, "TOOL_X") - value(&cycles[right - 1], "TOOL_X");
    assert!(dx > 10.0, "TOOL_X moved {dx} mm");
    assert!(
        (2.5..3.5).contains(&(c.t_s - cycles[right].t_s)),
        "unplugged {} s after the deflection",
        c.t_s - cycles[right].t_s
    );
    // Back and pulled: MOTION again, M moves down.
    let pulled = unplugged
        + cycles[unplugged..]
            .iter()
            .position(|c| value(c, "JOYSTICK_Y") == -1.0)
            .expect("the second deflection reached the process image");
    assert_eq!(flag(&cycles[pulled], "JOYSTICK_CONNECTED"), Some(true));
    assert_eq!(cycles[pulled].state, "MOTION");
    let centred = pulled
        + cycles[pulled..]
            .iter()
            .position(|c| value(c, "JOYSTICK_Y") == 0.0)
            .expect("the stick came back to the centre");
    let dy = value(&cycles[centred], "TOOL_Y") - value(&cycles[pulled - 1], "TOOL_Y");
    assert!(dy < -10.0, "TOOL_Y moved {dy} mm");
    assert_eq!(cycles.last().map(|c| c.state.as_str()), Some("READY"));

    // The joystick's values are inputs like any other: the run replays identically from its trace.
    common::assert_replays_identically(&trace, &["--config", config.to_str().expect("utf-8")]);
}
