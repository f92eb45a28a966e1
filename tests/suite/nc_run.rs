//! NC programs running on the machines (`run --program`), in virtual time: every machine's
//! acceptance programs complete within the contour tolerance and replay identically; feed hold
//! mid-arc stops on the path and resumes; STOP mid-program names the line; M0 pauses; M3/M5
//! drive the spindle output; a start away from the program's start is refused; a program that
//! cannot run is refused before anything moves.

use crate::common;

use common::{get, machine_config, pkm, stderr, transitions};
use pkm_api::trajectory::vars;
use pkm_plc::compose::{self, Options, Setup};
use pkm_plc::runtime::plc::Plc;

/// The repository's path of a file, as text.
fn repo(path: &str) -> String {
    common::root().join(path).to_str().expect("utf-8").to_string()
}

/// Builds `machine` (`trijoint`: the repository's config.json) on its simulated plant running
/// `program`, with the scenario `events` (a JSON array).
fn build(machine: &str, program: &std::path::Path, events: &str) -> Plc {
    let dir = tempfile::tempdir().expect("tempdir");
    let scenario = dir.path().join("scenario.json");
    std::fs::write(&scenario, format!(r#"{{"events": {events}}}"#)).expect("write the scenario");
    let loaded = if machine == "trijoint" {
        common::loaded(&common::repo_config())
    } else {
        machine_config(machine, |_| {})
    };
    let setup = Setup::new(loaded).expect("a known machine");
    let options = Options {
        scenario: Some(scenario),
        program: Some(program.to_path_buf()),
        ..Options::default()
    };
    compose::build(setup, options).unwrap_or_else(|e| panic!("{e}")).plc
}

/// Writes `text` as a program in `dir`; its path.
fn write_program(dir: &std::path::Path, text: &str) -> std::path::PathBuf {
    let path = dir.join("program.ngc");
    std::fs::write(&path, text).expect("write the program");
    path
}

#[test]
fn every_machine_runs_its_acceptance_programs_within_the_contour_tolerance_and_replays_them() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (machine, program, seconds) in [
        ("ox-x", "programs/ox-x-target.ngc", 90),
        ("ox-x", "programs/ox-x-text.ngc", 70),
        ("pn101", "programs/pn101-shapes.ngc", 150),
        ("hexapod", "programs/hexapod-tilted-circle.ngc", 30),
        ("trijoint", "programs/trijoint-circle-square.ngc", 70),
    ] {
        let summary = dir.path().join(format!("{machine}.summary.json"));
        let trace = dir.path().join(format!("{machine}.jsonl.gz"));
        let seconds = seconds.to_string();
        let config = if machine == "trijoint" {
            vec!["--config".to_string(), repo("config.json")]
        } else {
            vec!["--machine".to_string(), machine.to_string()]
        };
        let mut args = vec!["run", "--virtual", "--duration", &seconds, "--program", program];
        args.extend(config.iter().map(String::as_str));
        args.extend([
            "--summary",
            summary.to_str().expect("utf-8"),
            "--trace",
            trace.to_str().expect("utf-8"),
        ]);
        let o = pkm(&args);
        assert_eq!(o.status.code(), Some(0), "{program}: {}", stderr(&o));
        let s = common::read_json(&summary);
        let p = &s["program"];
        assert_eq!(s["main"]["state"], "READY", "{program}: back in READY at its end: {s}");
        assert_eq!(p["file"], program);
        assert_eq!(p["completed"], true, "{program}: {p}");
        let max = p["contour_error_mm"]["max"].as_f64().expect("a number");
        let rms = p["contour_error_mm"]["rms"].as_f64().expect("a number");
        assert!(max <= 0.02, "{program}: contour error {max} mm > 0.02 mm");
        assert!(rms > 0.0 && rms <= max, "{program}: RMS {rms}, max {max}");
        // At the programmed feed: the run lasts as long as its plan (no hold, no pause).
        let (run, planned) = (
            p["duration_s"].as_f64().expect("a number"),
            p["planned_s"].as_f64().expect("a number"),
        );
        assert!(
            (run - planned).abs() < 0.02,
            "{program}: ran {run} s, planned {planned} s"
        );
        assert!(p["path_length_mm"].as_f64().expect("a number") > 100.0, "{p}");
        for e in p["max_following_error_mm"].as_array().expect("per joint") {
            assert!(e.as_f64().expect("a number") < 0.05, "{program}: {p}");
        }
        let config: Vec<&str> = config.iter().map(String::as_str).collect();
        common::assert_replays_identically(&trace, &config);
    }
}

/// The O-X target part's first groove, a full circle of radius 10 mm at z = −0.5 mm (line 8):
/// when the executor works on it, in ms of simulated time.
fn first_groove_ms() -> (u64, u64) {
    let program = std::path::Path::new(common::root()).join("programs/ox-x-target.ngc");
    let mut plc = build("ox-x", &program, "[]");
    let (mut from, mut to) = (u64::MAX, 0);
    common::run(&mut plc, 40_000, |plc, t| {
        if get(plc, vars::NC_LINE) == 8 && get(plc, vars::NC_STATE) == 1 {
            from = from.min(t);
            to = to.max(t);
        }
    });
    assert!(from < to, "the groove was cut");
    (from, to)
}

#[test]
fn a_feed_hold_mid_arc_brakes_on_the_path_stands_and_resumes() {
    let (from, to) = first_groove_ms();
    let hold = (from + to) / 2;
    let resume = hold + 2000;
    let program = common::root().join("programs/ox-x-target.ngc");
    let events = format!(r#"[{{"at_ms": {hold}, "program": "hold"}}, {{"at_ms": {resume}, "program": "resume"}}]"#);
    let mut plc = build("ox-x", &program, &events);
    let mut states: Vec<i16> = Vec::new();
    let mut held_at: Option<(u64, f64)> = None;
    let mut worst_off_circle = 0.0f64;
    let seen = transitions(&mut plc, 100_000, |plc, t| {
        let state = get(plc, vars::NC_STATE);
        if states.last() != Some(&state) {
            states.push(state);
        }
        if (hold..resume).contains(&t) {
            // Braking and standing: on the groove's circle, at its depth.
            let [x, y, z] = [vars::NC_POSE[0], vars::NC_POSE[1], vars::NC_POSE[2]].map(|v| get(plc, v));
            worst_off_circle = worst_off_circle.max((x.hypot(y) - 10.0).abs()).max((z + 0.5).abs());
            assert_eq!(get(plc, vars::NC_LINE), 8, "at {t} ms");
            if state == 3 && held_at.is_none() {
                held_at = Some((t, get(plc, vars::NC_TIME_S)));
            }
            if let Some((_, stood)) = held_at {
                assert_eq!(get(plc, vars::NC_TIME_S), stood, "standing still at {t} ms");
                assert_eq!(common::state(plc), "AUTO");
            }
        }
    });
    let (held_ms, _) = held_at.expect("the program stood");
    // 10 mm/s braked within the path's tangential acceleration: well under a second.
    assert!(held_ms - hold < 500, "held {} ms after the press", held_ms - hold);
    assert!(worst_off_circle < 1e-6, "{worst_off_circle} mm off the groove");
    // Idle, running, holding, held, running, done (at the end idle again in READY).
    assert_eq!(states, [0, 1, 2, 3, 1, 5, 0], "{states:?}");
    let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
    assert_eq!(names, ["REBOOT", "INIT", "READY", "AUTO", "READY"], "{seen:?}");
    // The hold cost about its two seconds; the tool kept to the contour through it.
    let run = get(&plc, vars::NC_RUN_S);
    let planned = 66.78;
    assert!(run > planned + 1.9 && run < planned + 2.6, "{run} s");
    assert!(get(&plc, vars::NC_COMPLETED));
    let contour = get(&plc, vars::NC_CONTOUR_MAX);
    assert!(contour <= 0.02, "{contour} mm");
}

#[test]
fn stop_mid_program_is_error_with_the_line_and_the_program_starts_again_after_referencing() {
    let (from, to) = first_groove_ms();
    let stop = (from + to) / 2;
    let program = common::root().join("programs/ox-x-target.ngc");
    // STOP, its acknowledgement (after the lockout), referencing, then a start.
    let events = format!(
        r#"[{{"at_ms": {stop}, "input": "BUTTON_STOP", "value": true}},
            {{"at_ms": {}, "input": "BUTTON_STOP", "value": false}},
            {{"at_ms": {}, "input": "BUTTON_STOP", "value": true}},
            {{"at_ms": {}, "input": "BUTTON_STOP", "value": false}},
            {{"at_ms": {}, "program": "start"}}]"#,
        stop + 200,
        stop + 3000,
        stop + 3200,
        stop + 30_000
    );
    let mut plc = build("ox-x", &program, &events);
    let mut spindle_after_stop = false;
    let seen = transitions(&mut plc, stop + 110_000, |plc, t| {
        if (stop + 50..stop + 3000).contains(&t) {
            spindle_after_stop |= get(plc, vars::SPINDLE_ON);
        }
    });
    let error = seen.iter().find(|(_, s, _)| s == "ERROR").expect("ERROR");
    assert_eq!(error.2.as_deref(), Some("STOP (program line 8)"), "{seen:?}");
    assert!(error.0 - stop <= 50, "ERROR within a main cycle: {seen:?}");
    assert!(!spindle_after_stop, "the spindle stops with the drives");
    let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
    assert_eq!(
        names,
        [
            "REBOOT", "INIT", "READY", "AUTO", "ERROR", "REBOOT", "INIT", "READY", "AUTO", "READY"
        ],
        "{seen:?}"
    );
    assert!(get(&plc, vars::NC_COMPLETED), "the second run completed");
    assert!(get(&plc, vars::NC_CONTOUR_MAX) <= 0.02);
}

#[test]
fn m0_pauses_until_resumed_and_m3_m5_drive_the_spindle() {
    let dir = tempfile::tempdir().expect("tempdir");
    let program = write_program(dir.path(), "S1200 M4\nG1 X5 F600\nM0\nG1 X10\nM5\nG0 X0\nM2\n");
    // The program starts at O-X's READY (11.65 s); the pause comes about a second later.
    let mut plc = build("ox-x", &program, r#"[{"at_ms": 20000, "program": "resume"}]"#);
    let mut log: Vec<(i16, i32, bool, bool, f64)> = Vec::new();
    transitions(&mut plc, 30_000, |plc, _| {
        let entry = (
            get(plc, vars::NC_STATE),
            get(plc, vars::NC_LINE),
            get(plc, vars::SPINDLE_ON),
            get(plc, vars::SPINDLE_REVERSE),
            get(plc, vars::SPINDLE_RPM),
        );
        if log.last() != Some(&entry) {
            log.push(entry);
        }
    });
    let paused = log.iter().position(|e| e.0 == 3).expect("the program stood at the M0");
    assert_eq!(log[paused].1, 3, "standing on the M0's line: {log:?}");
    assert_eq!(
        (log[paused].2, log[paused].3, log[paused].4),
        (true, true, 1200.0),
        "M4 at 1200 rpm turns on through the pause: {log:?}"
    );
    let done = log.iter().position(|e| e.0 == 5).expect("done");
    assert!(done > paused, "{log:?}");
    assert!(!log[done].2 && log[done].4 == 0.0, "M5 stopped it: {log:?}");
    assert!(get(&plc, vars::NC_COMPLETED));
    // It stood from about 12.7 s until the resume at 20 s.
    let run = get(&plc, vars::NC_RUN_S);
    assert!(run > 8.0, "{run} s: the pause lasted until the resume");
}

#[test]
fn m7_m8_m9_switch_the_coolant_while_the_program_runs_and_stop_turns_it_off() {
    let dir = tempfile::tempdir().expect("tempdir");
    let program = write_program(dir.path(), "M8\nG1 X5 F600\nM7\nG1 X10\nM9\nG1 X5\nM8\nG1 X0\nM2\n");
    // The program starts at O-X's READY (11.65 s); STOP while the last move runs.
    let mut plc = build("ox-x", &program, "[]");
    let mut log: Vec<(i16, bool, bool)> = Vec::new();
    transitions(&mut plc, 30_000, |plc, _| {
        let entry = (
            get(plc, vars::NC_STATE),
            get(plc, vars::COOLANT_MIST),
            get(plc, vars::COOLANT_FLOOD),
        );
        if log.last() != Some(&entry) {
            log.push(entry);
        }
    });
    let mut coolant: Vec<(bool, bool)> = log.iter().map(|e| (e.1, e.2)).collect();
    coolant.dedup();
    assert_eq!(
        coolant,
        [
            (false, false),
            (false, true),
            (true, true),
            (false, false),
            (false, true),
            (false, false)
        ],
        "flood, mist too, off, flood, and off at the end: {log:?}"
    );
    assert!(get(&plc, vars::NC_COMPLETED));
    // STOP while a slow move runs with the flood on: ERROR, and the coolant off with it.
    let program = write_program(dir.path(), "M8\nG1 X5 F60\nG0 X0\nM2\n");
    let events = r#"[{"at_ms": 14000, "input": "BUTTON_STOP", "value": true}]"#;
    let mut plc = build("ox-x", &program, events);
    let (mut flooded, mut flooded_in_error) = (false, false);
    let seen = transitions(&mut plc, 16_000, |plc, _| {
        let on = get(plc, vars::COOLANT_FLOOD);
        flooded |= on;
        flooded_in_error |= on && plc.app_status().is_some_and(|s| s.state == "ERROR");
    });
    assert!(seen.iter().any(|(_, s, _)| s == "ERROR"), "{seen:?}");
    assert!(flooded, "the flood ran before the STOP");
    assert!(!flooded_in_error, "no coolant in ERROR");
}

#[test]
fn a_start_away_from_the_programs_start_is_refused_with_a_note() {
    let dir = tempfile::tempdir().expect("tempdir");
    let program = write_program(dir.path(), "G1 X5 F600\nG0 X0\nM2\n");
    // The program runs at READY and ends where it started; a jog moves the tool; a start then
    // is refused.
    let events = r#"[{"at_ms": 16000, "input": "BUTTON_RIGHT", "value": true},
                     {"at_ms": 17000, "input": "BUTTON_RIGHT", "value": false},
                     {"at_ms": 19000, "program": "start"}]"#;
    let mut plc = build("ox-x", &program, events);
    let seen = transitions(&mut plc, 21_000, |_, _| {});
    let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
    assert_eq!(
        names,
        ["REBOOT", "INIT", "READY", "AUTO", "READY", "MOTION", "READY"],
        "{seen:?}"
    );
    let status = plc.app_status().expect("status");
    assert_eq!(
        status.note,
        Some(
            "program not started: the tool is not at the program's start, the reference pose (STOP, acknowledge and reference to return there)"
        )
    );
}

/// Runs `program` on the O-X glide; it must be refused (exit 2): the message.
fn refused(program: &str) -> String {
    let o = pkm(&[
        "run",
        "--machine",
        "ox-x",
        "--virtual",
        "--duration",
        "5",
        "--program",
        program,
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(!e.contains("REBOOT"), "no PLC ran: {e}");
    e
}

#[test]
fn run_refuses_a_program_that_cannot_run_before_anything_moves() {
    let dir = tempfile::tempdir().expect("tempdir");
    let far = write_program(dir.path(), "G0 X10\nG1 X500 F600\nM2\n");
    let far = far.to_str().expect("utf-8");
    let e = refused(far);
    assert!(
        e.contains(&format!(
            "{far}: the program leaves what ox-x can reach; nothing moves:\n{far}:2: at "
        )),
        "{e}"
    );
    let bad = dir.path().join("bad.ngc");
    std::fs::write(&bad, "G1 X1 F600\nG5 X2\n").expect("write");
    let bad = bad.to_str().expect("utf-8");
    let e = refused(bad);
    assert!(e.contains(&format!("{bad}:2:1: ")), "{e}");
}

#[test]
fn trace_path_draws_the_programmed_and_the_actual_path_of_a_run_with_a_program() {
    let dir = tempfile::tempdir().expect("tempdir");
    let trace = dir.path().join("hexapod.jsonl.gz");
    let program = "programs/hexapod-tilted-circle.ngc";
    let o = pkm(&[
        "run",
        "--machine",
        "hexapod",
        "--virtual",
        "--duration",
        "25",
        "--program",
        program,
        "--trace",
        trace.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let svg = dir.path().join("path.svg");
    let o = pkm(&[
        "trace",
        "path",
        trace.to_str().expect("utf-8"),
        svg.to_str().expect("utf-8"),
        "--magnify",
        "200",
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let text = std::fs::read_to_string(&svg).expect("the drawing");
    assert!(
        text.contains(&format!(
            "{program}: programmed (grey) and actual (blue) tool path, deviation ×200"
        )),
        "the caption"
    );
    assert!(
        text.contains("contour error on feed moves: max 0.0"),
        "the error's panel"
    );
    assert!(
        text.contains("x [mm, machine frame]") && text.contains("y [mm]"),
        "the circle's plane"
    );
    // A trace without a program has nothing to draw.
    let plain = common::record_machine_trace(dir.path(), "plain.jsonl", 2, "[]", &["--machine", "hexapod"]);
    let o = pkm(&[
        "trace",
        "path",
        plain.to_str().expect("utf-8"),
        svg.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("recorded without a program: record one with `run --program FILE --trace …`"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn the_hexapod_in_auto_shows_the_line_its_six_pose_coordinates_and_all_six_joints() {
    let program = common::root().join("programs/hexapod-tilted-circle.ngc");
    let mut plc = build("hexapod", &program, "[]");
    let mut shown: Option<Vec<String>> = None;
    common::run(&mut plc, 40_000, |plc, _| {
        if shown.is_none()
            && let Some(s) = plc.app_status().filter(|s| s.state == "AUTO")
        {
            shown = Some(s.values.iter().map(|(n, _)| n.to_string()).collect());
        }
    });
    let shown = shown.expect("the program ran");
    assert_eq!(
        shown,
        ["line", "x", "y", "z", "a", "b", "c", "q1", "q2", "q3", "q4", "q5", "q6"],
        "nothing cut"
    );
}

/// M62 … M68 on the O-X glide in virtual time: the digital output M62 sets comes on with the
/// next move's start and M63's goes off with the one after; M68's analog output and M64's digital
/// one are set with the tool standing; M66 waits for an input nothing drives for its 0.5 s
/// timeout, then the program goes on; all are off at the end and in ERROR — a STOP while an
/// output is on takes it off in that cycle. The run replays identically from its trace.
#[test]
fn program_outputs_follow_the_moves_m66_waits_and_every_safe_state_is_off() {
    let dir = tempfile::tempdir().expect("tempdir");
    let program = write_program(
        dir.path(),
        "G1 F600 X5\nM62 P0\nM68 E0 Q2.5\nG1 X10\nM66 P1 L3 Q0.5\nM63 P0\nG1 X0\nM64 P2\nG4 P1\nM2\n",
    );
    // Per 10 ms cycle: (t, line, NC_STATE, DOUT_0, DOUT_2, AOUT_0, x commanded).
    let observe = |events: &str, until_ms: u64| {
        let mut plc = build("ox-x", &program, events);
        let mut seen = Vec::new();
        let seen_states = transitions(&mut plc, until_ms, |plc, t| {
            seen.push((
                t,
                get(plc, vars::NC_LINE),
                get(plc, vars::NC_STATE),
                get(plc, vars::NC_DOUT[0]),
                get(plc, vars::NC_DOUT[2]),
                get(plc, vars::NC_AOUT[0]),
                get(plc, vars::NC_POSE[0]),
            ));
        });
        (seen, seen_states)
    };
    let (seen, states) = observe("[]", 40_000);
    let names: Vec<&str> = states.iter().map(|(_, s, _)| s.as_str()).collect();
    assert_eq!(names, ["REBOOT", "INIT", "READY", "AUTO", "READY"], "{states:?}");
    // DOUT_0: on with line 4's move (M62 on line 2), off with line 7's (M63 on line 6, which
    // moves nothing): on while lines 4 and 5 execute (the M66 included), never on 1 or 7.
    let mut on_lines: Vec<i32> = seen.iter().filter(|s| s.3).map(|s| s.1).collect();
    on_lines.dedup();
    assert_eq!(on_lines, [4, 5], "NC_DOUT_0");
    let first_on = seen.iter().find(|s| s.3).expect("DOUT_0 on");
    assert!(
        first_on.6 > 5.0 - 1e-6 && first_on.6 < 5.2,
        "on as line 4 starts from X5: {first_on:?}"
    );
    // AOUT_0 from line 3 (the tool standing at X5, for less than a cycle: the 10 ms cycles see
    // it as line 4 starts) to the end of the run: never while line 1 moves.
    assert!(
        seen.iter().filter(|s| s.1 == 1).all(|s| s.5 == 0.0),
        "AOUT_0 not before M68"
    );
    let aout_at = seen.iter().find(|s| s.5 == 2.5).expect("AOUT_0 set");
    assert!(aout_at.6 > 5.0 - 1e-6 && aout_at.6 < 5.2, "set at X5: {aout_at:?}");
    // M66 L3 on NC_DIN_1, which nothing drives: it waits its 0.5 s (code 8), then goes on.
    let waiting: Vec<u64> = seen.iter().filter(|s| s.2 == 8).map(|s| s.0).collect();
    let waited_ms = waiting.last().expect("waited") - waiting[0];
    assert!((400..=550).contains(&waited_ms), "{waited_ms} ms at the M66");
    // DOUT_2: from M64 (line 8, the tool standing at X0 after line 7's move) through the
    // second's dwell (the line shown stays 7's, whose end the dwell stands at); off at the end
    // with everything else.
    let dout2: Vec<_> = seen.iter().filter(|s| s.4).collect();
    assert!(
        dout2.iter().all(|s| s.6.abs() < 1e-6),
        "on standing at X0 only: {dout2:?}"
    );
    assert!(
        (98..=106).contains(&dout2.len()),
        "on for the dwell's second: {} cycles of 10 ms",
        dout2.len()
    );
    let last = seen.last().expect("cycles");
    assert_eq!(
        (last.3, last.4, last.5),
        (false, false, 0.0),
        "all off after the program: {last:?}"
    );
    // STOP while DOUT_0 is on: ERROR, and the output off from then on.
    let stop = first_on.0 + 200;
    let (seen, states) = observe(
        &format!(
            r#"[{{"at_ms": {stop}, "input": "BUTTON_STOP", "value": true}}, {{"at_ms": {}, "input": "BUTTON_STOP", "value": false}}]"#,
            stop + 200
        ),
        stop + 1_000,
    );
    let error_at = states.iter().find(|(_, s, _)| s == "ERROR").expect("ERROR").0;
    assert!(seen.iter().any(|s| s.0 < error_at && s.3), "on before the STOP");
    assert!(
        seen.iter()
            .filter(|s| s.0 >= error_at)
            .all(|s| !s.3 && !s.4 && s.5 == 0.0),
        "off in ERROR"
    );
    // Traced and replayed: the outputs are in the trace and the replay reproduces them.
    let trace = dir.path().join("io.jsonl");
    let o = pkm(&[
        "run",
        "--machine",
        "ox-x",
        "--virtual",
        "--duration",
        "40",
        "--program",
        program.to_str().expect("utf-8"),
        "--trace",
        trace.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let text = std::fs::read_to_string(&trace).expect("the trace");
    for recorded in [
        r#""NC_DOUT_0":true"#,
        r#""NC_DOUT_2":true"#,
        r#""NC_AOUT_0":2.5"#,
        r#""NC_STATE":8"#,
    ] {
        assert!(text.contains(recorded), "{recorded} in the trace");
    }
    common::assert_replays_identically(&trace, &["--machine", "ox-x"]);
}

/// Laser mode (`nc.laser`) on the O-X glide engraving a square with M4 in virtual time: the
/// beam's power is S over `s_max` times the tool's speed over the programmed feed at every cycle
/// — so it dips through every corner, where the tool slows — and zero through every rapid, after
/// M5 and at the end; with M3 it is constant while the tool feeds. The run replays identically.
#[test]
fn laser_power_follows_the_speed_through_corners_and_is_off_through_rapids() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut config = common::read_json(&common::root().join("machines/ox-x.json"));
    config["io_map"] = common::root().join("io-map/ox-x.json").to_str().expect("utf-8").into();
    config["nc"]["laser"] = serde_json::json!({"s_max": 1000});
    let config_path = common::write_config(dir.path(), "ox-x-laser.json", &config);
    let program = write_program(
        dir.path(),
        "G21 G90 G64 P0.05\nG0 X2 Y2\nM4 S800\nG1 X10 F1200\nY10\nX2\nY2\nG0 X0 Y0\nM3 S500\nG1 X5 F600\nM5\nG0 X0\nM2\n",
    );
    let loaded = pkm_plc::runtime::config::load(Some(&config_path)).unwrap_or_else(|e| panic!("{e}"));
    let setup = Setup::new(loaded).expect("a known machine");
    let options = Options {
        program: Some(program.clone()),
        ..Options::default()
    };
    let mut plc = compose::build(setup, options).unwrap_or_else(|e| panic!("{e}")).plc;
    // Per 10 ms cycle: (line, power, commanded feed mm/min).
    let mut seen = Vec::new();
    let states = transitions(&mut plc, 40_000, |plc, _| {
        seen.push((
            get(plc, vars::NC_LINE),
            get(plc, vars::LASER_POWER),
            get(plc, vars::NC_FEED),
        ));
    });
    let names: Vec<&str> = states.iter().map(|(_, s, _)| s.as_str()).collect();
    assert_eq!(names, ["REBOOT", "INIT", "READY", "AUTO", "READY"], "{states:?}");
    // M4 on lines 4 … 7 at F1200: power = 0.8 × speed / 1200 mm/min, every cycle.
    let square: Vec<_> = seen.iter().filter(|s| (4..=7).contains(&s.0)).collect();
    assert!(square.len() > 100, "{} cycles on the square", square.len());
    for (line, power, feed) in &square {
        let expected = 0.8 * (feed / 1200.0).clamp(0.0, 1.0);
        assert!(
            (power - expected).abs() < 1e-9,
            "line {line}: power {power}, speed {feed} mm/min"
        );
    }
    // Through the corners the tool slows and the beam with it; on the straights it is full
    // (within the executor's last step to the programmed feed).
    let full = square.iter().filter(|s| s.1 > 0.79).count();
    let dipped = square.iter().filter(|s| s.1 < 0.6 && s.1 > 0.0).count();
    assert!(
        full > 50 && dipped >= 3,
        "{full} cycles at full power, {dipped} through corners"
    );
    // Rapids (lines 2, 8, 12): off; M3 on line 10: constant 0.5 while it feeds; M5: off.
    for (line, power, _) in &seen {
        match line {
            2 | 8 | 12 => assert_eq!(*power, 0.0, "a rapid on line {line}"),
            10 => assert!(
                *power == 0.5 || *power == 0.0,
                "M3's constant power on line 10: {power}"
            ),
            _ => {}
        }
    }
    assert!(
        seen.iter().filter(|s| s.0 == 10).filter(|s| s.1 == 0.5).count() > 30,
        "M3 on line 10"
    );
    assert_eq!(seen.last().map(|s| s.1), Some(0.0), "off at the end");
    // Traced and replayed.
    let trace = dir.path().join("laser.jsonl");
    let config_arg = config_path.to_str().expect("utf-8");
    let o = pkm(&[
        "run",
        "--config",
        config_arg,
        "--virtual",
        "--duration",
        "40",
        "--program",
        program.to_str().expect("utf-8"),
        "--trace",
        trace.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(
        std::fs::read_to_string(&trace)
            .expect("the trace")
            .contains(r#""LASER_POWER":0.5"#)
    );
    common::assert_replays_identically(&trace, &["--config", config_arg]);
    // Feed per revolution has no spindle to follow: refused at its word, before anything runs.
    let g95 = write_program(
        dir.path(),
        "G21 G0 X2
M3 S500
G95 G1 X5 F0.1
M2
",
    );
    let o = pkm(&["nc", "check", g95.to_str().expect("utf-8"), "--config", config_arg]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains(":3:1: G95 (feed per revolution) is refused in laser mode (nc.laser): S is the beam's power, not a spindle's speed; feed per minute (G94)"),
        "{}",
        stderr(&o)
    );
}

/// A manual tool change confirmed in virtual time by a scenario (the panel's tool-changed
/// button every shipped joint machine's I/O map binds to `TOOL_CHANGED`): the program stands at
/// `T2 M6` until the scenario puts tool 2 in, then runs to its end with tool 2 in the spindle;
/// the run replays identically. The TRIJOINT, whose station has no free input, refuses such a
/// scenario and says why.
#[test]
fn a_scenario_confirms_a_tool_change_in_virtual_time_and_the_run_replays() {
    let dir = tempfile::tempdir().expect("tempdir");
    let program = write_program(dir.path(), "T2 M6\nG1 F600 X5\nG0 X0\nM2\n");
    let table = dir.path().join("tool.tbl");
    std::fs::write(&table, "T2 P2 Z10 D3 ;3 mm drill\n").expect("the tool table");
    let scenario = dir.path().join("change.json");
    std::fs::write(&scenario, r#"{"events": [{"at_ms": 20000, "tool_changed": 2}]}"#).expect("the scenario");
    let summary = dir.path().join("summary.json");
    let trace = dir.path().join("change.jsonl");
    let o = pkm(&[
        "run",
        "--machine",
        "ox-x",
        "--virtual",
        "--duration",
        "30",
        "--program",
        program.to_str().expect("utf-8"),
        "--tool-table",
        table.to_str().expect("utf-8"),
        "--scenario",
        scenario.to_str().expect("utf-8"),
        "--summary",
        summary.to_str().expect("utf-8"),
        "--trace",
        trace.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let s = common::read_json(&summary);
    assert_eq!(s["program"]["completed"], true, "{s}");
    // It stood at the change until the press at 20 s: the run took about 20 s less READY's
    // 11.65 s plus its moves.
    let run_s = s["program"]["duration_s"].as_f64().expect("a number");
    assert!(run_s > 8.0, "stood at the tool change: ran {run_s} s");
    let text = std::fs::read_to_string(&trace).expect("the trace");
    for recorded in [r#""TOOL_CHANGE":true"#, r#""TOOL_CHANGED":true"#, r#""TOOL_NUMBER":2"#] {
        assert!(text.contains(recorded), "{recorded} in the trace");
    }
    common::assert_replays_identically(&trace, &["--machine", "ox-x"]);
    // The TRIJOINT's panel has no such button.
    let o = pkm(&[
        "run",
        "--config",
        &repo("config.json"),
        "--virtual",
        "--duration",
        "1",
        "--scenario",
        scenario.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("change.json: at events[0].tool_changed: ")
            && stderr(&o).contains("io-map/trijoint.json binds no panel button of the machine to TOOL_CHANGED: this machine's simulated panel has no tool-changed button"),
        "{}",
        stderr(&o)
    );
}
