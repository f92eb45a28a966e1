//! The command line as a user runs it: exit codes, messages, summaries.

use crate::common;

use std::process::Command;

use common::{pkm, stderr, stdout};

#[test]
fn check_accepts_the_default_configuration() {
    let o = pkm(&["check"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert_eq!(
        String::from_utf8_lossy(&o.stdout),
        "config.json: valid (3 task classes: fast (10 ms), main (50 ms), spare (100 ms); 71 process-image variables; I/O map: io-map/trijoint.json)\n"
    );
}

#[test]
fn check_refuses_a_bad_configuration_with_exit_code_2() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("bad.json");
    std::fs::write(
        &path,
        r#"{"task_classes": [{"name": "x", "cycle_us": 10, "tolerance_us": 0, "priority": 1, "programs": []}]}"#,
    )
    .expect("write");
    let o = pkm(&["check", "--config", path.to_str().expect("utf-8 path")]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        stderr(&o),
        format!(
            "error: {}: at task_classes[0].cycle_us: cycle time must be between 200 and 10000000 µs, got 10\n",
            path.display()
        )
    );
}

#[test]
fn check_reports_the_problems_of_the_configuration_and_its_io_map_together() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut config = common::repo_config();
    config["task_classes"][1]["programs"][0]["params"] = serde_json::json!({"dead_zone": 5});
    config["io_map"] = "map.json".into();
    let config_path = common::write_config(dir.path(), "config.json", &config);
    let mut map = common::read_json(&common::root().join("io-map/trijoint.json"));
    map["bindings"][0]["module"] = "NOPE".into();
    std::fs::write(dir.path().join("map.json"), map.to_string()).expect("write");
    let o = pkm(&["check", "--config", config_path.to_str().expect("utf-8")]);
    assert_eq!(o.status.code(), Some(2));
    let (c, m) = (config_path.display(), dir.path().join("map.json").display().to_string());
    assert_eq!(
        stderr(&o),
        format!(
            "error: {c}: at task_classes[1].programs[0].params.dead_zone: must be between 0 and 0.9 (a fraction of \
             full deflection), got 5\n{m}: at bindings[0].module: unknown module \"NOPE\"; modules in this map: DI, DO, \
             DC_LEFT, DC_RIGHT, MM, JOY\n"
        )
    );
}

#[test]
fn an_io_map_that_is_a_device_or_a_fifo_is_refused_at_once() {
    let dir = tempfile::tempdir().expect("tempdir");
    let fifo = dir.path().join("fifo.json");
    assert!(Command::new("mkfifo").arg(&fifo).status().expect("mkfifo").success());
    for (map, what) in [
        ("/dev/zero", "a character device"),
        (fifo.to_str().expect("utf-8"), "a FIFO"),
    ] {
        let mut config = common::repo_config();
        config["io_map"] = map.into();
        let path = common::write_config(dir.path(), "config.json", &config);
        let o = pkm(&["check", "--config", path.to_str().expect("utf-8")]);
        assert_eq!(o.status.code(), Some(2));
        assert_eq!(
            stderr(&o),
            format!("error: {map}: cannot read the file: {what}: only a regular file can be read here\n")
        );
    }
}

#[test]
fn a_missing_configuration_file_is_a_clear_error() {
    let o = pkm(&["run", "--config", "/nonexistent.json", "--virtual", "--duration", "1"]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        stderr(&o),
        "error: /nonexistent.json: cannot read the file: No such file or directory (os error 2)\n"
    );
}

#[test]
fn virtual_needs_a_duration_or_a_pace() {
    let o = pkm(&["run", "--virtual"]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        stderr(&o).trim_end(),
        "error: --virtual needs --duration (the simulated seconds it runs), or --pace X (a simulation paced at X times real time, with the screen, until stopped)"
    );
    let o = pkm(&["run", "--virtual", "--duration", "-3"]);
    assert_eq!(o.status.code(), Some(2));
    // A pace is 1 … 50 times real time, of a virtual run, on the simulated machine.
    let o = pkm(&["run", "--virtual", "--pace", "60"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("a simulation runs at 1 … 50 times real time, got 60"),
        "{}",
        stderr(&o)
    );
    let o = pkm(&["run", "--pace", "10", "--duration", "1"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("--virtual"), "{}", stderr(&o));
    let o = pkm(&["run", "--virtual", "--pace", "10", "--bus", "none"]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        stderr(&o).trim_end(),
        "error: --pace simulates the machine: it runs on --bus sim only (a real station would see its cycles paced, not timed)"
    );
}

#[test]
fn a_virtual_run_writes_its_summary() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("summary.json");
    let o = pkm(&[
        "run",
        "--virtual",
        "--duration",
        "60",
        "--summary",
        path.to_str().expect("utf-8 path"),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let s = common::read_json(&path);
    assert_eq!(s["mode"], "virtual");
    assert_eq!(s["duration_s"], 60.0);
    let cycles: Vec<u64> = s["task_classes"]
        .as_array()
        .expect("classes")
        .iter()
        .map(|c| c["cycles"].as_u64().expect("n"))
        .collect();
    assert_eq!(cycles, [6000, 1200, 600]);
    assert_eq!(s["task_classes"][0]["lateness_us"]["max"], 0.0);
    // The default configuration runs the TRIJOINT application: referenced and READY within 60 s.
    assert_eq!(s["main"]["state"], "READY");
    assert_eq!(s["main"]["error_reason"], serde_json::Value::Null);
}

#[test]
fn an_output_path_that_cannot_be_written_fails_before_the_run() {
    // Exit 2 at once: not after the run's hour.
    let o = pkm(&[
        "run",
        "--virtual",
        "--duration",
        "3600",
        "--summary",
        "/nonexistent/x.json",
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert_eq!(
        stderr(&o),
        "error: /nonexistent/x.json: cannot write: No such file or directory (os error 2)\n"
    );
    assert!(!stderr(&o).contains("virtual time"), "the run did not start");
}

#[test]
fn a_serial_line_too_slow_for_the_exchange_is_refused_before_it_is_opened() {
    // The hexapod over a port that does not exist, at 115 200 baud.
    let hexapod = |more: &[&str]| {
        let port = ["--bus", "serial:/dev/pkm-plc-no-such-port@115200"];
        let run = ["run", "--machine", "hexapod", "--hmi", "none", "--duration", "1"];
        let args = [&run[..], &port[..], more].concat();
        let o = pkm(&args);
        (o.status.code(), stderr(&o))
    };
    // Its packed image (60 bytes) takes 9.23 ms there, over the 8 ms an exchange may take: every
    // exchange would be a bus fault. Refused before the port is opened and before anything
    // runs, with the next rate that will do.
    assert_eq!(
        hexapod(&[]),
        (
            Some(2),
            "error: --bus: one exchange (image, 60 bytes in 1 transaction, 9.23 ms at 115200 baud) takes longer \
             on the wire than the 8 ms an exchange may take (--max-exchange-ms, what the drive regulators are \
             tuned for): every exchange would be a bus fault; a faster line will do: 230400 baud takes 6.36 ms; \
             or a larger --max-exchange-ms once the regulators are checked for slower inputs\n"
                .to_string()
        )
    );
    // A larger bound is the user's to give: then the line is only too slow to open here.
    let (code, log) = hexapod(&["--max-exchange-ms", "12"]);
    assert_eq!(code, Some(1), "{log}");
    assert!(
        log.ends_with(
            "error: serial:/dev/pkm-plc-no-such-port@115200: the bus never came up: 4 failed exchanges in a row, \
             the last: cannot connect: No such file or directory\n"
        ),
        "{log}"
    );
}

#[test]
fn bus_none_is_a_dry_run_of_the_programs_with_one_warning() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("summary.json");
    let o = pkm(&[
        "run",
        "--virtual",
        "--duration",
        "2",
        "--bus",
        "none",
        "--summary",
        path.to_str().expect("utf-8 path"),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let log = stderr(&o);
    let warnings: Vec<&str> = log.lines().filter(|l| l.contains("WARN")).collect();
    assert!(
        warnings[0].contains(
            "--bus none: a dry run of the programs without field I/O: the inputs of the I/O map (BUTTON_STOP, \
             BUTTON_LEFT,"
        ),
        "{warnings:?}"
    );
    assert!(
        warnings[0].ends_with("JOYSTICK_CONNECTED) hold zero / false, the outputs go nowhere"),
        "{warnings:?}"
    );
    let s = common::read_json(&path);
    assert_eq!(s["bus"], "none");
    assert_eq!(s["task_classes"][0]["cycles"], 200);
    // No machine behind it: the referencing finds no switch, as on a machine with no power.
    assert_eq!(s["main"]["state"], "ERROR");
}

#[test]
fn a_real_time_run_ends_after_its_duration_with_a_summary() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("summary.json");
    let o = pkm(&[
        "run",
        "--duration",
        "0.3",
        "--time-source",
        "timerfd",
        "--summary",
        path.to_str().expect("utf-8 path"),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let s = common::read_json(&path);
    assert_eq!(s["mode"], "real-time");
    assert_eq!(s["time_source"], "timerfd");
    let fast = &s["task_classes"][0];
    assert_eq!(
        fast["cycles"].as_u64().unwrap_or(0) + fast["missed"].as_u64().unwrap_or(0),
        30
    );
}

#[test]
fn sigterm_stops_a_real_time_run_cleanly() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("summary.json");
    let mut child = crate::common::pkm_command()
        .args(["run", "--summary", path.to_str().expect("utf-8 path")])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env("RUST_LOG", "info")
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("spawn");
    // Wait for the readiness line (handlers installed, cycles started), not for a guessed time.
    let mut log = std::io::BufReader::new(child.stderr.take().expect("stderr"));
    let mut seen = String::new();
    loop {
        let mut line = String::new();
        let n = std::io::BufRead::read_line(&mut log, &mut line).expect("read the log");
        assert!(n > 0, "the run ended before it was ready:\n{seen}");
        seen.push_str(&line);
        if line.contains("running in real time") {
            break;
        }
    }
    nix_kill(child.id());
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut log, &mut rest).expect("read the log");
    let status = child.wait().expect("wait");
    assert_eq!(status.code(), Some(0), "{seen}{rest}");
    assert!(rest.contains("SIGTERM: stopping"), "{rest}");
    let s = common::read_json(&path);
    assert!(s["task_classes"][0]["cycles"].as_u64().unwrap_or(0) > 0);
}

fn nix_kill(pid: u32) {
    let status = Command::new("kill")
        .args(["-TERM", &pid.to_string()])
        .status()
        .expect("kill runs");
    assert!(status.success());
}

#[test]
fn without_privileges_the_run_warns_and_goes_on() {
    // Needs root to drop to an unprivileged user; CI runs as root. Elsewhere there is nothing to
    // drop, and the same code path is what an unprivileged user runs anyway.
    let is_root = std::fs::read_to_string("/proc/self/status")
        .map(|s| {
            s.lines()
                .any(|l| l.starts_with("Uid:") && l.split_whitespace().nth(1) == Some("0"))
        })
        .unwrap_or(false);
    let setpriv = std::path::Path::new("/usr/bin/setpriv");
    if !is_root || !setpriv.exists() {
        eprintln!("not root or no setpriv: running as the current user instead");
    }
    let dir = tempfile::tempdir().expect("tempdir");
    // The unprivileged user must be able to run the binary: copy it somewhere world-readable.
    let exe = dir.path().join("pkm-plc");
    std::fs::copy(env!("CARGO_BIN_EXE_pkm-plc"), &exe).expect("copy binary");
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755)).expect("chmod dir");
    std::fs::set_permissions(&exe, std::fs::Permissions::from_mode(0o755)).expect("chmod exe");
    let mut cmd = if is_root && setpriv.exists() {
        let mut c = Command::new(setpriv);
        c.args(["--reuid", "65534", "--regid", "65534", "--clear-groups"])
            .arg(&exe);
        c
    } else {
        Command::new(&exe)
    };
    let o = cmd
        .args(["run", "--duration", "0.3"])
        .current_dir(dir.path())
        .env("RUST_LOG", "warn")
        .env("PKM_PLC_OPCUA", "none")
        .output()
        .expect("runs");
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    if is_root && setpriv.exists() {
        let err = stderr(&o);
        assert!(err.contains("could not get real-time priority SCHED_FIFO 80"), "{err}");
        assert!(err.contains("running with normal scheduling"), "{err}");
    }
}

#[test]
fn kin_fk_and_ik_print_one_json_object() {
    let o = pkm(&["kin", "trijoint", "fk", "0", "0"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        out.starts_with("{\"machine\":\"trijoint\",\"joints\":[0.0,0.0],\"pose\":{\"x\":318.055"),
        "{out}"
    );
    let v: serde_json::Value = serde_json::from_str(&out).expect("json");
    let (x, y) = (v["pose"]["x"].as_f64().expect("x"), v["pose"]["y"].as_f64().expect("y"));
    let o = pkm(&["kin", "trijoint", "ik", &x.to_string(), &y.to_string()]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let back: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    for q in back["joints"].as_array().expect("joints") {
        assert!(q.as_f64().expect("number").abs() < 1e-9, "{back}");
    }
    let o = pkm(&["kin", "hexapod", "ik", "10", "-20", "520", "3", "-4", "5"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    let keys: Vec<&String> = v["pose"].as_object().expect("pose").keys().collect();
    assert_eq!(keys, ["x", "y", "z", "a", "b", "c"]);
    assert_eq!(v["joints"].as_array().map(Vec::len), Some(6));
}

#[test]
fn kin_unreachable_input_exits_1_with_the_reason() {
    let o = pkm(&["kin", "trijoint", "ik", "100", "500"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(o.stdout.is_empty());
    assert_eq!(
        stderr(&o),
        "error: joint 2 = 384.673380 mm is outside its travel 0 … 250 mm\n"
    );
    let o = pkm(&["kin", "ox-x", "fk", "0", "0"]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(stderr(&o), "error: expected 3 joint values, got 2\n");
    let o = pkm(&["kin", "delta", "fk", "0"]);
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn kin_workspace_draws_an_svg() {
    let dir = tempfile::tempdir().expect("tempdir");
    let svg = dir.path().join("ws.svg");
    let o = pkm(&[
        "kin",
        "ox-o",
        "workspace",
        "--svg",
        svg.to_str().expect("utf-8"),
        "--samples",
        "30",
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    assert_eq!(summary["samples"], 900);
    assert!(summary["reachable"].as_u64().unwrap_or(0) > 450, "{summary}");
    let text = std::fs::read_to_string(&svg).expect("svg written");
    assert!(
        text.starts_with("<svg") && text.contains("<circle"),
        "not an SVG scatter plot"
    );
}

#[test]
fn kinematic_parameters_are_checked_with_their_paths() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("k.json");
    let base: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config.json")).expect("config"),
    )
    .expect("json");
    let mut bad = base.clone();
    // The copy lives elsewhere: point it at the repository's I/O map.
    bad["io_map"] = serde_json::json!(concat!(env!("CARGO_MANIFEST_DIR"), "/io-map/trijoint.json"));
    bad["kinematics"] = serde_json::json!({"trijoint": {"l3": -4, "h1_travel": [250, 0]}, "hexapod": {"struts": 6}});
    std::fs::write(&path, bad.to_string()).expect("write");
    let o = pkm(&["check", "--config", path.to_str().expect("utf-8")]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        stderr(&o),
        format!(
            "error: {}: at kinematics.hexapod.struts: unknown field `struts`, expected one of `base`, `platform`, `home`, \
             `strut_travel`, `max_iterations`, `tolerance_mm`, `divergence_bound_mm`\n",
            path.display()
        )
    );
    bad["kinematics"] = serde_json::json!({"trijoint": {"l3": -4, "h1_travel": [250, 0]}});
    std::fs::write(&path, bad.to_string()).expect("write");
    let o = pkm(&[
        "kin",
        "trijoint",
        "fk",
        "0",
        "0",
        "--config",
        path.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        stderr(&o),
        format!(
            "error: {}: 2 problems:\n  at kinematics.trijoint.l3: must be a positive length in mm, at most 10000, got -4.0\n  \
             at kinematics.trijoint.h1_travel: travel must be [min, max] with min < max, within ±10000 mm, got [250.0, 0.0]\n",
            path.display()
        )
    );
}

#[test]
fn a_time_source_with_virtual_time_is_a_usage_error() {
    let o = pkm(&["run", "--virtual", "--duration", "1", "--time-source", "tokio"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("cannot be used with"), "{}", stderr(&o));
}

/// A run in virtual time for `duration` seconds of the scenario `text`, written to `path`.
fn virtual_run(path: &std::path::Path, text: &str, duration: &str) -> std::process::Output {
    std::fs::write(path, text).expect("write the scenario");
    pkm(&[
        "run",
        "--virtual",
        "--duration",
        duration,
        "--scenario",
        path.to_str().expect("utf-8"),
    ])
}

#[test]
fn a_scenario_says_how_long_its_run_lasts() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("s.json");
    std::fs::write(
        &path,
        r#"{"duration_s": 0.5, "events": [{"at_ms": 200, "input": "BUTTON_STOP", "value": true}]}"#,
    )
    .expect("write");
    let summary = dir.path().join("summary.json");
    // No --duration: the scenario's ends the run (real time; nothing served).
    let o = common::pkm_command()
        .args(["run", "--scenario", path.to_str().expect("utf-8")])
        .args(["--hmi", "none", "--opcua", "none", "--joystick", "none"])
        .args(["--summary", summary.to_str().expect("utf-8")])
        .env("RUST_LOG", "info")
        .output()
        .expect("the binary runs");
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("the scenario lasts 0.5 s: the run ends then (--duration overrides)"),
        "{}",
        stderr(&o)
    );
    let written: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&summary).expect("summary")).expect("JSON");
    assert_eq!(written["main"]["state"], "ERROR", "STOP at 0.2 s: {written}");
    // Ended by the scenario (a busy machine may end it a little late; it does not run on).
    let ran = written["duration_s"].as_f64().expect("duration_s");
    assert!((0.4..10.0).contains(&ran), "{written}");
    // One that would end before its last event is refused.
    let o = virtual_run(
        &path,
        r#"{"duration_s": 0.1, "events": [{"at_ms": 200, "input": "BUTTON_STOP", "value": true}]}"#,
        "1",
    );
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        stderr(&o),
        format!(
            "error: {}: at duration_s: 0.1 s ends the run before the last event, at 0.2 s\n",
            path.display()
        )
    );
}

#[test]
fn run_takes_a_scenario_and_refuses_a_bad_one() {
    let o = pkm(&[
        "run",
        "--virtual",
        "--duration",
        "3",
        "--scenario",
        "scenarios/faults.json",
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("s.json");
    let o = virtual_run(
        &path,
        r#"{"events": [{"at_ms": 1, "fault": "bridge_error", "drive": "middle"}]}"#,
        "3",
    );
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        stderr(&o),
        format!(
            "error: {}: at events[0].drive: no drive \"middle\" on this machine: use \"left\" or \"right\"\n",
            path.display()
        )
    );
    let o = pkm(&[
        "run",
        "--virtual",
        "--duration",
        "3",
        "--bus",
        "none",
        "--scenario",
        "scenarios/faults.json",
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        stderr(&o),
        "error: --scenario needs the simulated bus (--bus sim and an io_map in the configuration)\n"
    );
}

#[test]
fn joystick_sources_that_cannot_work_are_said_clearly() {
    // In virtual time a joystick path is a capture file: anything else is refused before
    // anything starts.
    let o = pkm(&["run", "--virtual", "--duration", "1", "--joystick", "/dev/input/event7"]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        stderr(&o),
        "error: --joystick /dev/input/event7: No such file or directory (os error 2) (in virtual time --joystick \
         plays a capture file; a device or FIFO needs real time)\n"
    );
    // A missing device is no reason to stop the machine: a warning, panel buttons, exit 0.
    let o = pkm(&["run", "--duration", "0.3", "--joystick", "/nonexistent/event0"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(
        stderr(&o).contains(
            "joystick: /nonexistent/event0: No such file or directory (os error 2) (trying again every second)"
        ),
        "{}",
        stderr(&o)
    );
    // Neither a device, a FIFO nor a file.
    let o = pkm(&["run", "--duration", "0.3", "--joystick", "/tmp"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("joystick: /tmp: not an input device, FIFO or capture file"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn a_program_of_a_machine_the_configuration_does_not_name_is_refused_with_its_machine() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut config = common::repo_config();
    let object = config.as_object_mut().expect("an object");
    for key in ["machine", "plant", "kinematics"] {
        object.remove(key);
    }
    let path = common::write_config(dir.path(), "no-machine.json", &config);
    let o = pkm(&["check", "--config", path.to_str().expect("utf-8")]);
    assert_eq!(o.status.code(), Some(2));
    let stderr = stderr(&o);
    let lines: Vec<&str> = stderr.lines().collect();
    assert_eq!(lines[0], format!("error: {}: 3 problems:", path.display()));
    assert_eq!(
        lines[1],
        "  at task_classes[0].programs[0].program: unknown program \"trijoint.encoders\"; known programs: \
         selftest.producer, selftest.consumer, selftest.idle (\"trijoint.encoders\" is a program of machine \
         \"trijoint\"; this configuration names no machine: set \"machine\": \"trijoint\")"
    );
}

#[test]
fn a_plant_section_problem_is_reported_once_by_run() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut config = common::repo_config();
    config["io_map"] = common::root()
        .join("io-map/trijoint.json")
        .to_str()
        .expect("utf-8")
        .into();
    config["plant"] = serde_json::json!({"left": {"tau_s": -1}});
    let path = common::write_config(dir.path(), "bad-plant.json", &config);
    let o = pkm(&[
        "run",
        "--virtual",
        "--duration",
        "1",
        "--config",
        path.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(
        stderr(&o),
        format!(
            "error: {}: at plant.left.tau_s: must be between 0.0001 and 10 s, got -1\n",
            path.display()
        )
    );
}

#[test]
fn machine_names_a_machines_configuration_file_or_its_built_in_copy() {
    for name in ["pn101", "ox-x", "ox-o", "hexapod"] {
        let o = pkm(&["check", "--machine", name]);
        assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
        assert!(
            stdout(&o).starts_with(&format!("machines/{name}.json: valid (2 task classes")),
            "{}",
            stdout(&o)
        );
    }
    // Elsewhere, without the file: the copy built into the binary, with its built-in I/O map.
    let dir = tempfile::tempdir().expect("tempdir");
    let o = crate::common::pkm_command()
        .args(["check", "--machine", "hexapod"])
        .current_dir(dir.path())
        .output()
        .expect("runs");
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(
        stdout(&o).starts_with("<built-in machines/hexapod.json>: valid (2 task classes: fast (10 ms), main (50 ms); 136 process-image variables; I/O map: ../io-map/hexapod.json)"),
        "{}",
        stdout(&o)
    );
    let o = pkm(&["check", "--machine", "pn101", "--config", "config.json"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("cannot be used with"), "{}", stderr(&o));
    let o = pkm(&["check", "--machine", "pn102"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("[possible values: trijoint, pn101, ox-x, ox-o, hexapod]"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn programs_to_load_need_the_screen_and_a_directory_that_can_be_listed() {
    let o = pkm(&["run", "--virtual", "--duration", "1", "--programs", "programs"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains(
            "--programs programs: programs are loaded from the operator's screen or over OPC UA, which are served in real time or in a paced simulation only (and not with both --hmi none and --opcua none)"
        ),
        "{}",
        stderr(&o)
    );
    let o = pkm(&[
        "run",
        "--duration",
        "1",
        "--hmi",
        "127.0.0.1:0",
        "--programs",
        "no-such-dir",
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("--programs no-such-dir: cannot list the directory: No such file or directory"),
        "{}",
        stderr(&o)
    );
}

/// `--programs DIR` offers the directory's own programs only — a symbolic link out of
/// it is skipped and logged, as are a directory, a FIFO (which would block the start) and other
/// names; a link to a program inside it is offered.
#[test]
fn programs_never_come_from_outside_their_directory_and_what_is_skipped_is_logged() {
    let dir = tempfile::tempdir().expect("tempdir");
    let outside = tempfile::tempdir().expect("tempdir");
    let root = crate::common::root();
    let library = dir.path().join("library");
    std::fs::create_dir(&library).expect("a directory");
    std::fs::copy(root.join("programs/ox-x-target.ngc"), library.join("target.ngc")).expect("copy");
    std::fs::copy(root.join("programs/ox-x-target.ngc"), outside.path().join("secret.ngc")).expect("copy");
    std::os::unix::fs::symlink(outside.path().join("secret.ngc"), library.join("escape.ngc")).expect("symlink");
    std::os::unix::fs::symlink(library.join("target.ngc"), library.join("again.ngc")).expect("symlink");
    std::fs::create_dir(library.join("folder.ngc")).expect("a directory");
    let fifo = std::ffi::CString::new(library.join("pipe.ngc").to_str().expect("utf-8")).expect("a path");
    // SAFETY: mkfifo(3) with a NUL-terminated path we own.
    assert_eq!(unsafe { libc::mkfifo(fifo.as_ptr(), 0o600) }, 0);
    std::fs::write(library.join("notes.txt"), "not a program").expect("write");
    let o = crate::common::pkm_command()
        .args([
            "run",
            "--machine",
            "ox-x",
            "--duration",
            "0.3",
            "--hmi",
            "127.0.0.1:0",
            "--joystick",
            "none",
        ])
        .args(["--programs", library.to_str().expect("utf-8")])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env("RUST_LOG", "info")
        .output()
        .expect("the binary runs");
    let log = stderr(&o);
    assert_eq!(o.status.code(), Some(0), "{log}");
    let lib = library.display();
    for skipped in [
        format!(
            "--programs: skipped {lib}/escape.ngc: a symbolic link out of the directory (to {}): only the directory's own programs are offered",
            outside
                .path()
                .join("secret.ngc")
                .canonicalize()
                .expect("canonical")
                .display()
        ),
        format!("--programs: skipped {lib}/folder.ngc: a directory, not a program file"),
        format!("--programs: skipped {lib}/pipe.ngc: a FIFO, not a program file"),
        format!("--programs {lib}: 1 entries without the .ngc extension ignored"),
    ] {
        assert!(log.contains(&skipped), "{skipped}\nnot in:\n{log}");
    }
    assert!(!log.contains("secret.ngc: "), "{log}");
    assert!(!log.contains("not offered"), "{log}");
}

#[test]
fn a_screen_address_that_is_taken_is_refused_before_anything_runs() {
    let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("a port");
    let addr = taken.local_addr().expect("its address").to_string();
    let o = pkm(&["run", "--machine", "ox-x", "--hmi", &addr, "--duration", "0.3"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(
        err.contains(&format!("operator screen: cannot listen on {addr}: "))
            && err.contains("(another pkm-plc, or another server, has it); give another address with --hmi ADDR"),
        "{err}"
    );
    assert!(!err.contains("READY") && !err.contains("INIT"), "nothing ran: {err}");
}

#[test]
fn a_program_or_a_scenario_of_another_machine_names_the_machine_it_is_for() {
    let o = pkm(&[
        "run",
        "--virtual",
        "--duration",
        "1",
        "--program",
        "programs/hexapod-tilted-circle.ngc",
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains(
            "programs/hexapod-tilted-circle.ngc:4:11: Z: this machine's axes are X Y\n(it runs on machine hexapod: --machine hexapod)"
        ),
        "{}",
        stderr(&o)
    );
    let dir = tempfile::tempdir().expect("tempdir");
    let scenario = dir.path().join("scenario.json");
    std::fs::write(
        &scenario,
        r#"{"events":[{"at_ms":100,"input":"BUTTON_AXES","value":true}]}"#,
    )
    .expect("write");
    let o = pkm(&[
        "run",
        "--virtual",
        "--duration",
        "1",
        "--scenario",
        scenario.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("no input variable \"BUTTON_AXES\" in io-map/trijoint.json wired to the machine (machines pn101, ox-x, ox-o, hexapod have it: --machine NAME)"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn the_examples_of_the_cli_reference_print_what_it_shows() {
    let doc = std::fs::read_to_string(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/cli.md"))
        .expect("docs/cli.md");
    let lines: Vec<&str> = doc.lines().collect();
    let mut checked = 0;
    for (i, line) in lines.iter().enumerate() {
        let Some(command) = line.strip_prefix("$ pkm-plc ") else {
            continue;
        };
        let args: Vec<&str> = command.split_whitespace().collect();
        let shown = lines.get(i + 1).copied().unwrap_or_default();
        let o = pkm(&args);
        let printed = if o.status.success() { stdout(&o) } else { stderr(&o) };
        assert_eq!(
            printed.trim_end(),
            shown,
            "docs/cli.md line {}: pkm-plc {command}",
            i + 1
        );
        checked += 1;
    }
    assert!(checked >= 3, "the examples are found: {checked}");
}
