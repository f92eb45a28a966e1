//! The OPC UA server end to end, in real time, with a client nobody here wrote: Python's asyncua
//! (from PyPI, in a virtual environment under `target/`; without python3-venv or PyPI the tests
//! that need it are skipped and say why, `common::skip`). It browses the address space and reads every
//! variable's type, unit and value, subscribes and counts the updates over 10 s, is refused a
//! method in an anonymous session, logs in over an encrypted channel (its certificate first
//! rejected, then trusted as an administrator would) to stop the machine, acknowledge and load a
//! program — and the trace of that run replays identically. A malformed hello is refused without
//! harm, and the options that would expose the machine are refused before anything runs.

use crate::common;

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use serde_json::Value as Json;

/// The virtual environment's Python (with asyncua), made on first use; `Err`: why there is none.
fn python() -> Result<PathBuf, String> {
    common::python_interop().map_err(|e| format!("no asyncua: {e}"))
}

/// The virtual environment's Python, or `None` once the test `name` has said why it skips.
fn python_or_skip(name: &str) -> Option<PathBuf> {
    python().map_err(|why| common::skip(name, &why)).ok()
}

/// Writes the users file `users.json` holding `users` into `dir` with `mode`; its path.
fn users_file(dir: &Path, users: &str, mode: u32) -> PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let file = dir.join("users.json");
    std::fs::write(&file, users).expect("users");
    std::fs::set_permissions(&file, std::fs::Permissions::from_mode(mode)).expect("chmod");
    file
}

/// The users file of the one operator with a password.
const OPERATOR: &str = r#"{"users": [{"name": "operator", "password": "a-long-passphrase"}]}"#;

/// The login of [`OPERATOR`]'s user, as the client script takes it.
const OPERATOR_LOGIN: [&str; 4] = ["--user", "operator", "--password", "a-long-passphrase"];

/// The first event of condition `name` in `alarms`' answer.
fn first_event<'a>(out: &'a Json, name: &str) -> &'a Json {
    out["events"]
        .as_array()
        .and_then(|e| e.iter().find(|e| e["name"] == name))
        .unwrap_or_else(|| panic!("no {name} event: {out}"))
}

/// A running `pkm-plc run` with its OPC UA server, killed when dropped.
struct Plc {
    run: common::Logged,
    url: String,
    /// Holds the run's configuration.
    dir: tempfile::TempDir,
}

impl Plc {
    /// Starts `pkm-plc run ARGS --opcua opc.tcp://127.0.0.1:0` and waits for the server's URL.
    fn start(args: &[&str]) -> Plc {
        Plc::serving("opc.tcp://127.0.0.1:0", args)
    }

    /// Starts `pkm-plc run ARGS --opcua URL` and waits for the server's URL (with its host
    /// replaced by 127.0.0.1: a server on every address announces this computer's name).
    /// The TRIJOINT as configured, save that these tests of OPC UA, not of timing, log a late
    /// cycle on a busy machine rather than raise ERROR ([`common::busy_machine_config`]).
    fn serving(url: &str, args: &[&str]) -> Plc {
        Plc::configured(common::busy_machine_config(), url, args)
    }

    /// Starts `pkm-plc run ARGS --opcua URL` with the configuration `config`, as
    /// [`Plc::serving`].
    fn configured(config: Json, url: &str, args: &[&str]) -> Plc {
        let dir = tempfile::tempdir().expect("tempdir");
        let json = config;
        let config = dir.path().join("trijoint.json");
        std::fs::write(&config, json.to_string()).expect("the configuration");
        let mut command = common::pkm_command();
        command
            .args(["run", "--opcua", url])
            // No screen unless the test asks for one.
            .args(if args.contains(&"--hmi") {
                &[][..]
            } else {
                &["--hmi", "none"][..]
            })
            .args(["--config", config.to_str().expect("utf-8")])
            .args(args)
            .env("RUST_LOG", "info");
        let (run, announced) = common::Logged::start(command, "OPC UA server at ", Duration::from_secs(60));
        let port = announced.rsplit(':').next().unwrap_or_default().trim_end_matches('/');
        let url = format!("opc.tcp://127.0.0.1:{port}/");
        Plc { run, url, dir }
    }

    /// The run's configuration file.
    fn config(&self) -> String {
        self.dir
            .path()
            .join("trijoint.json")
            .to_str()
            .expect("utf-8")
            .to_string()
    }

    fn log(&self) -> String {
        self.run.log()
    }

    /// The operator screen's URL, for a run started with `--hmi`.
    fn screen(&self) -> String {
        let log = self.log();
        log.lines()
            .find_map(|l| l.split("operator screen at ").nth(1))
            .and_then(|rest| rest.split_whitespace().next())
            .unwrap_or_else(|| panic!("no screen: {log}"))
            .to_string()
    }
}

/// Runs the client script with `args`; its last stdout line as JSON.
fn client(python: &Path, args: &[&str]) -> Json {
    let mut command = Command::new(python);
    command.arg(format!("{}/tests/interop/opcua_client.py", env!("CARGO_MANIFEST_DIR")));
    last_json(command, args)
}

/// Runs the client script's `command` (`call`, `alarms`) on the TRIJOINT at `url`, logged in
/// with `login` (none: anonymous), carrying out `steps`; its answer.
fn client_steps(python: &Path, command: &str, url: &str, login: &[&str], steps: &[&str]) -> Json {
    let mut args = vec![command, url, "trijoint"];
    args.extend_from_slice(login);
    args.extend_from_slice(steps);
    client(python, &args)
}

/// Runs `command` (a client script, its interpreter and path) with `args`: it must succeed, and
/// its last stdout line is its answer, as JSON.
fn last_json(mut command: Command, args: &[&str]) -> Json {
    let o = command.args(args).output().expect("the client runs");
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "client {args:?} failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let last = stdout.lines().last().unwrap_or_default();
    serde_json::from_str(last).unwrap_or_else(|e| panic!("{e}: {stdout}"))
}

#[test]
fn a_client_browses_every_variable_with_its_type_and_unit_and_subscribes_at_the_main_cycle_rate() {
    let Some(python) = python_or_skip(
        "opcua::a_client_browses_every_variable_with_its_type_and_unit_and_subscribes_at_the_main_cycle_rate",
    ) else {
        return;
    };
    // Ended by SIGTERM once the clients are done (each takes seconds on a busy machine).
    let mut plc = Plc::start(&["--duration", "300"]);
    // On loopback: the unsecured endpoint besides the secure ones; anonymous sessions only
    // (no users file).
    // Each at the URL the client used: the host it asked with, the port the server was started on.
    let endpoints = client(&python, &["endpoints", &plc.url]);
    let url = plc.url.as_str();
    assert_eq!(
        endpoints,
        serde_json::json!([
            ["Aes256_Sha256_RsaPss", "SignAndEncrypt", ["Anonymous"], url],
            ["Basic256Sha256", "Sign", ["Anonymous"], url],
            ["Basic256Sha256", "SignAndEncrypt", ["Anonymous"], url],
            ["None", "None_", ["Anonymous"], url]
        ])
    );
    let survey = client(&python, &["survey", &plc.url, "trijoint"]);

    // Every process-image variable, in the folder of its class, with its IEC type and the OPC
    // UA type that carries it.
    let vars = survey["vars"].as_object().expect("vars");
    assert!(vars.len() >= 60, "{} variables", vars.len());
    let mut types = std::collections::BTreeSet::new();
    for (name, v) in vars {
        let iec = v["iec"].as_str().unwrap_or_else(|| panic!("{name}: no IecType: {v}"));
        let expected = match iec {
            "BOOL" => "Boolean",
            "INT" => "Int16",
            "UINT" => "UInt16",
            "DINT" => "Int32",
            "REAL" => "Double",
            other => panic!("{name}: IEC type {other}"),
        };
        assert_eq!(v["type"], expected, "{name}: {v}");
        assert_eq!(v["variant"], expected, "{name}: the value's own type: {v}");
        types.insert(iec.to_string());
    }
    assert_eq!(types.len(), 5, "every IEC type is read: {types:?}");
    let var = |name: &str| &vars[name];
    assert_eq!(var("JOINT1_POSITION")["class"], "fast");
    assert_eq!(var("JOINT1_POSITION")["unit"], "mm");
    assert_eq!(var("JOINT1_POSITION")["unit_id"], 5_066_068);
    assert_eq!(var("TOOL_X")["unit"], "mm");
    assert_eq!(var("TOOL_X")["class"], "main");
    assert_eq!(var("setpoint_left_mm_s")["unit"], "mm/s");
    assert_eq!(var("NC_FEED_OVERRIDE")["unit"], "%");
    assert_eq!(var("counts_left")["iec"], "DINT");
    assert!(var("counts_left").get("unit").is_none(), "a count has no unit");
    assert_eq!(var("period_duration")["iec"], "UINT");
    assert_eq!(var("HMI_STOP")["value"], false);
    // An integrator's types: a value with a unit is an AnalogItem with its EURange where the
    // range is known (the overrides, clamped by the PLC), else a BaseAnalog (a counter's
    // position since power-on); a BOOL never has a unit.
    assert_eq!(var("NC_FEED_OVERRIDE")["typedef"], "AnalogItemType");
    assert_eq!(var("NC_FEED_OVERRIDE")["range"], serde_json::json!([0.0, 150.0]));
    assert_eq!(var("NC_RAPID_OVERRIDE")["range"], serde_json::json!([0.0, 100.0]));
    assert_eq!(var("JOINT1_POSITION")["typedef"], "BaseAnalogType");
    assert_eq!(var("counts_left")["typedef"], "BaseDataVariableType");
    for (name, v) in vars {
        let analog = v["typedef"] == "AnalogItemType";
        assert_eq!(
            analog,
            v.get("range").is_some(),
            "{name}: an AnalogItem has its EURange: {v}"
        );
        if v["iec"] == "BOOL" {
            assert!(v.get("unit").is_none(), "{name}: a BOOL with a unit: {v}");
        }
    }
    // Real source timestamps: none before the server started (1970-01-01 once), none after
    // the read; the server's CurrentTime advances (read alone and in ServerStatus).
    let times = &survey["server_time"];
    let (start, here) = (
        times["start"].as_f64().expect("start"),
        times["here"].as_f64().expect("here"),
    );
    for (name, v) in vars {
        let at = v["source_ts"]
            .as_f64()
            .unwrap_or_else(|| panic!("{name}: no source timestamp: {v}"));
        assert!(
            at > start - 5.0 && at < here + 1.0,
            "{name}: {at} (start {start}, read {here})"
        );
    }
    for current in ["current", "current_in_status"] {
        let t = times[current].as_f64().expect("a time");
        assert!(t >= start && (t - here).abs() < 2.0, "{current}: {times}");
    }
    // The state as a number beside its text: a MultiStateDiscrete named by its EnumStrings.
    let main = &survey["main_state"];
    assert_eq!(main["typedef"], "MultiStateDiscreteType", "{main}");
    assert_eq!(main["type"], "UInt32", "{main}");
    assert_eq!(
        main["enum_strings"],
        serde_json::json!(["REBOOT", "INIT", "READY", "MOTION", "ERROR", "AUTO"])
    );
    // (Read a moment after the text: the referencing may have ended in between.)
    let named = main["value"]
        .as_u64()
        .and_then(|v| main["enum_strings"][v as usize].as_str());
    assert!(matches!(named, Some("REBOOT" | "INIT" | "READY")), "{main}");
    // The classes with their cycle times and figures; the program's variables; the state.
    let classes = &survey["classes"];
    for (class, ms) in [("fast", 10.0), ("main", 50.0), ("spare", 100.0)] {
        assert_eq!(classes[class]["CycleTimeMs"], ms, "{classes}");
        assert!(classes[class]["Cycles"].as_u64().is_some_and(|c| c > 0), "{classes}");
    }
    let program: Vec<&str> = survey["program"]
        .as_array()
        .expect("program")
        .iter()
        .filter_map(Json::as_str)
        .collect();
    assert!(
        program.contains(&"NC_LINE") && program.contains(&"NC_STATE"),
        "{program:?}"
    );
    assert!(
        ["REBOOT", "INIT"].contains(&survey["state"].as_str().unwrap_or_default()),
        "{survey}"
    );
    // Anonymous: the methods are there, none executable by this session.
    let methods = survey["methods"].as_object().expect("methods");
    let names: Vec<&str> = methods.keys().map(String::as_str).collect();
    for m in ["Stop", "Acknowledge", "Start", "Hold", "Resume", "Load"] {
        assert!(names.contains(&m), "{names:?}");
        assert_eq!(methods[m], false, "{m} executable anonymously");
    }

    // Data changes flow at the main cycle's rate: 200 main cycles in 10 s, nearly all of which
    // a client on a quiet machine receives (docs/performance.md: every one). A Python client on
    // a busy machine takes fewer (93 beside two CPU-bound processes: its publish requests come
    // late and the server's queue of 4 per item drops the oldest), so the bounds here tell a
    // flowing subscription from a stalled or duplicating one, not the client's speed.
    let sub = client(&python, &["subscribe", &plc.url, "trijoint", "10"]);
    let counts = &sub["counts"];
    let cycles = counts["trijoint.TaskClasses.main.Cycles"].as_u64().unwrap_or(0);
    assert!((50..=205).contains(&cycles), "main cycles updates in 10 s: {sub}");
    // While the machine references, a joint moves and its position's changes flow too (on a
    // busy machine the client may start only once the referencing is over: then nothing moves).
    let log = plc.log();
    if !log.contains(" s: READY") && !log.contains(" s: ERROR") {
        let joints: u64 = ["trijoint.JOINT1_POSITION", "trijoint.JOINT2_POSITION"]
            .iter()
            .map(|j| counts[*j].as_u64().unwrap_or(0))
            .sum();
        assert!(joints >= 25, "the referencing moves a joint: {sub}");
    }
    assert!(counts["trijoint.State"].as_u64().unwrap_or(0) >= 1, "{sub}");
    eprintln!("update latency to the client: {}", sub["latency_ms"]);

    // An anonymous session is refused a command before it runs.
    let refused = client(&python, &["call", &plc.url, "trijoint", "Stop"]);
    assert_eq!(refused["steps"][0]["status"], "BadUserAccessDenied", "{refused}");
    assert!(!plc.log().contains("ERROR (STOP)"), "{}", plc.log());
    assert!(plc.run.terminate().success(), "{}", plc.log());
}

#[test]
fn users_on_encrypted_channels_stop_acknowledge_and_load_beyond_loopback_and_the_trace_replays() {
    let Some(python) = python_or_skip(
        "opcua::users_on_encrypted_channels_stop_acknowledge_and_load_beyond_loopback_and_the_trace_replays",
    ) else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let path = |name: &str| dir.path().join(name).to_str().expect("utf-8").to_string();
    // A user who logs in with a password, one with a certificate (made by the client's tools).
    client(&python, &["usercert", &path("cell-7")]);
    users_file(
        dir.path(),
        r#"{"users": [{"name": "operator", "password": "a-long-passphrase"}, {"name": "cell-7", "certificate": "cell-7/cert.der"}]}"#,
        0o600,
    );
    let (pki, trace) = (path("pki"), path("opcua.jsonl"));
    // On every address (so with users), as on the lab's network.
    // Ended by SIGTERM once the clients are done (each client takes seconds on a busy machine).
    let mut plc = Plc::serving(
        "opc.tcp://0.0.0.0:0",
        &[
            "--duration",
            "300",
            "--opcua-users",
            &path("users.json"),
            "--opcua-pki",
            &pki,
            "--trace",
            &trace,
        ],
    );
    // Beyond loopback: the secure endpoints only, each with every kind of login, and each at
    // the host the client asked with and the port the server was started on — here through
    // another address than the one it was started on (every address), as a client on the
    // lab's network reaches it.
    let via = plc.url.replace("127.0.0.1", "127.0.0.2");
    let endpoints = client(&python, &["endpoints", &via]);
    let logins = serde_json::json!(["Anonymous", "Certificate", "UserName"]);
    assert_eq!(
        endpoints,
        serde_json::json!([
            ["Aes256_Sha256_RsaPss", "SignAndEncrypt", logins, via],
            ["Basic256Sha256", "Sign", logins, via],
            ["Basic256Sha256", "SignAndEncrypt", logins, via]
        ])
    );
    let secure = ["--secure".to_string(), path("client"), "--pki".to_string(), pki.clone()];
    let call = |login: &[&str], steps: &[&str]| {
        let mut args = vec!["call", via.as_str(), "trijoint"];
        args.extend(secure.iter().map(String::as_str));
        args.extend_from_slice(login);
        args.extend_from_slice(steps);
        client(&python, &args)
    };
    // A wrong password: no session. The client's certificate was unknown, so its first
    // connection was refused and the administrator trusted it.
    let wrong = call(&["--user", "operator", "--password", "a-wrong-passphrase"], &["Stop"]);
    assert_eq!(wrong["refused"], "BadUserAccessDenied", "{wrong}");
    assert_eq!(wrong["untrusted_first"], true, "{wrong}");

    let out = call(
        &OPERATOR_LOGIN,
        &[
            "Stop",
            "wait=ERROR",
            "Stop",
            "Acknowledge",
            "wait=INIT",
            "Acknowledge",
            "Load=1",
            "Load=9",
            "Start",
        ],
    );
    assert_eq!(out["untrusted_first"], false, "trusted now: {out}");
    let steps: Vec<(String, String)> = out["steps"]
        .as_array()
        .expect("steps")
        .iter()
        .map(|s| {
            let what = s["step"].as_str().unwrap_or_default().to_string();
            let outcome = s
                .get("status")
                .or_else(|| s.get("state"))
                .and_then(Json::as_str)
                .unwrap_or_default();
            (what, outcome.to_string())
        })
        .collect();
    let expected = [
        ("Stop", "Good"),
        ("wait=ERROR", "ERROR"),
        ("Stop", "BadInvalidState"),
        ("Acknowledge", "Good"),
        ("wait=INIT", "INIT"),
        ("Acknowledge", "BadInvalidState"),
        ("Load=1", "Good"),
        ("Load=9", "BadOutOfRange"),
        ("Start", "BadInvalidState"),
    ];
    let expected: Vec<(String, String)> = expected.iter().map(|(a, b)| (a.to_string(), b.to_string())).collect();
    assert_eq!(steps, expected, "{out}");
    assert_eq!(
        out["steps"][6]["result"], "program 1 (programs/trijoint-circle-square.ngc) loaded",
        "{out}"
    );
    // The user with a certificate stops the machine too.
    let cell = call(&["--user-cert", &path("cell-7")], &["Stop", "wait=ERROR"]);
    assert_eq!(cell["steps"][0]["status"], "Good", "{cell}");
    assert_eq!(cell["steps"][1]["state"], "ERROR", "{cell}");

    let log = plc.log();
    for line in [
        "OPC UA: login refused: user \"operator\": unknown user or wrong password",
        "OPC UA: user \"operator\" logged in (password)",
        "OPC UA: user \"cell-7\" logged in (certificate)",
        // Who commanded, and what came of it.
        "OPC UA: user \"operator\": Stop: STOP pressed",
        "ERROR (STOP)",
        "OPC UA: user \"operator\": Acknowledge refused (BadInvalidState): there is no error to acknowledge: the machine is in INIT",
        "OPC UA: user \"operator\": Start refused (BadInvalidState): the machine is in INIT: a program starts in READY",
        "OPC UA: user \"operator\": Load: program 1 (programs/trijoint-circle-square.ngc) loaded",
        "OPC UA: user \"cell-7\": Stop: STOP pressed",
    ] {
        assert!(log.contains(line), "{line}\n{log}");
    }
    let status = plc.run.terminate();
    assert!(status.success(), "{status}");
    // The commands entered the process image as inputs: the run replays.
    common::assert_replays_identically(Path::new(&trace), &["--config", &plc.config()]);
}

/// The events of one condition, as `alarms` reports them: (active, acked, retain, message).
fn condition_events(out: &Json, name: &str) -> Vec<(bool, bool, bool, String)> {
    out["events"]
        .as_array()
        .expect("events")
        .iter()
        .filter(|e| e["name"] == name)
        .map(|e| {
            (
                e["active"].as_bool().unwrap_or_default(),
                e["acked"].as_bool().unwrap_or_default(),
                e["retain"].as_bool().unwrap_or_default(),
                e["message"].as_str().unwrap_or_default().to_string(),
            )
        })
        .collect()
}

/// The outcome of each step of `alarms`.
fn step_outcomes(out: &Json) -> Vec<(String, String)> {
    out["steps"]
        .as_array()
        .expect("steps")
        .iter()
        .map(|s| {
            (
                s["step"].as_str().unwrap_or_default().to_string(),
                s["status"].as_str().unwrap_or_default().to_string(),
            )
        })
        .collect()
}

/// Alarms and conditions as a SCADA sees them: STOP raises the `Stop` condition (an
/// AlarmConditionType, severity 600, "ERROR: STOP"); an anonymous session sees it on a refresh
/// but may not acknowledge it; the operator's Acknowledge acknowledges the PLC (an input, so the
/// trace replays) and the condition clears when the PLC leaves ERROR. The station vanishing
/// raises `BusFault` (a SystemOffNormalAlarmType), then its ERROR.
#[test]
fn conditions_are_raised_acknowledged_and_cleared_as_the_plc_sees_them() {
    let name = "opcua::conditions_are_raised_acknowledged_and_cleared_as_the_plc_sees_them";
    let Some(python) = python_or_skip(name) else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let path = |name: &str| dir.path().join(name).to_str().expect("utf-8").to_string();
    users_file(dir.path(), OPERATOR, 0o600);
    let (station, address) = common::start_io_sim("127.0.0.1:0", &[]);
    let trace = path("alarms.jsonl");
    let mut plc = Plc::start(&[
        "--duration",
        "300",
        "--bus",
        &format!("tcp:{address}"),
        "--opcua-users",
        &path("users.json"),
        "--trace",
        &trace,
    ]);
    let alarms = |login: &[&str], steps: &[&str]| client_steps(&python, "alarms", &plc.url, login, steps);
    // STOP: the condition rises, unacknowledged.
    let out = alarms(&OPERATOR_LOGIN, &["refresh", "Stop", "wait=Stop:active"]);
    assert_eq!(
        step_outcomes(&out)[1..],
        [
            ("Stop".into(), "Good".into()),
            ("wait=Stop:active".into(), "Good".into())
        ],
        "{out}"
    );
    assert_eq!(
        condition_events(&out, "Stop"),
        [(true, false, true, "ERROR: STOP".to_string())],
        "{out}"
    );
    let raised = first_event(&out, "Stop");
    assert_eq!(raised["severity"], 600, "{raised}");
    assert_eq!(raised["type"], "AlarmConditionType", "{raised}");
    assert_eq!(raised["condition"], "ns=2;s=trijoint.Alarms.Stop", "{raised}");
    // A session that connects later sees it on its refresh; anonymous, it may not acknowledge.
    let anonymous = alarms(&[], &["refresh", "wait=Stop:active", "ack=Stop"]);
    assert_eq!(
        step_outcomes(&anonymous),
        [
            ("refresh".into(), "Good".into()),
            ("wait=Stop:active".into(), "Good".into()),
            ("ack=Stop".into(), "BadUserAccessDenied".into())
        ],
        "{anonymous}\n{}",
        plc.log()
    );
    // The refresh is whole through the client's AlarmConditionType filter: its start and end
    // markers (OPC 10000-9, 4.5) around the condition it sends again.
    let types: Vec<&str> = anonymous["events"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|e| e["type"].as_str())
        .collect();
    let start = types.iter().position(|t| *t == "RefreshStartEventType");
    let end = types.iter().position(|t| *t == "RefreshEndEventType");
    assert!(
        matches!((start, end), (Some(s), Some(e)) if s < e && types[s + 1..e].contains(&"AlarmConditionType")),
        "{anonymous}"
    );
    // The operator acknowledges the condition: the PLC leaves ERROR and the condition clears.
    let out = alarms(
        &OPERATOR_LOGIN,
        &["refresh", "wait=Stop:active", "ack=Stop", "wait=Stop:inactive"],
    );
    assert!(step_outcomes(&out).iter().all(|(_, s)| s == "Good"), "{out}");
    let seen = condition_events(&out, "Stop");
    assert_eq!(
        seen[1..],
        [
            (true, true, true, "ERROR: STOP".to_string()),
            (false, true, false, "REBOOT after the acknowledgement".to_string())
        ],
        "{out}"
    );
    // What happened just now, from the history: the main state READY (or INIT) → ERROR →
    // REBOOT → INIT, each code once, in time order; read again 5 values a read.
    let history = client(&python, &["history", &plc.url, "trijoint", "MainState", "120", "5"]);
    let values = history["values"].as_array().expect("values");
    let codes: Vec<u64> = values.iter().filter_map(|v| v[1].as_u64()).collect();
    let error_at = codes.iter().position(|c| *c == 4).expect("ERROR in the history");
    assert_eq!(codes.get(error_at + 1), Some(&0), "REBOOT after ERROR: {history}");
    assert!(
        values.windows(2).all(|w| w[0][0].as_f64() <= w[1][0].as_f64()),
        "{history}"
    );
    assert_eq!(history["in_parts"].as_u64(), Some(values.len() as u64), "{history}");
    assert_eq!(
        history["reads"].as_u64(),
        Some((values.len() as u64).div_ceil(5).max(1)),
        "{history}"
    );
    // The station vanishes: the bus fault, then the ERROR it brings.
    let _ = alarms(&OPERATOR_LOGIN, &["wait=Stop:inactive"]);
    drop(station);
    let out = alarms(&OPERATOR_LOGIN, &["refresh", "wait=BusFault:active", "sleep=2"]);
    let bus = condition_events(&out, "BusFault");
    assert!(bus.iter().all(|(active, acked, _, _)| *active && !acked), "{out}");
    assert!(
        bus.iter()
            .any(|(_, _, _, m)| m.starts_with(&format!("ERROR: bus fault: tcp:{address}"))),
        "{out}"
    );
    // Every one names the station and its cause, the first too (raised by the bus before the
    // PLC's ERROR for it).
    assert!(
        bus.iter().all(|(_, _, _, m)| m
            .trim_start_matches("ERROR: ")
            .starts_with(&format!("bus fault: tcp:{address}: "))),
        "{out}"
    );
    let bus_event = first_event(&out, "BusFault");
    assert_eq!(bus_event["type"], "SystemOffNormalAlarmType", "{bus_event}");
    assert_eq!(bus_event["severity"], 800, "{bus_event}");
    let log = plc.log();
    for line in [
        "OPC UA: user \"operator\": Acknowledge: the error acknowledged",
        "OPC UA: user \"operator\" acknowledged the condition Stop (by the test): ERROR: STOP",
    ] {
        assert!(log.contains(line), "{line}\n{log}");
    }
    assert!(plc.run.terminate().success(), "{}", plc.log());
    // The acknowledgement entered the process image: the run replays.
    common::assert_replays_identically(Path::new(&trace), &["--config", &plc.config()]);
}

/// What an MES sees of OPC 40001-1 Machinery: the machine in `Machines`, found by browse path
/// through the DI and Machinery namespaces; its nameplate from the configuration; its building
/// blocks; and its Machinery states following the PLC's: referencing (INIT) is Executing in Setup,
/// ERROR is OutOfService in no mode, the acknowledgement brings back Setup.
#[test]
fn machinery_shows_the_machine_its_nameplate_and_states_that_follow_the_plc() {
    let Some(python) =
        python_or_skip("opcua::machinery_shows_the_machine_its_nameplate_and_states_that_follow_the_plc")
    else {
        return;
    };
    let mut config = common::busy_machine_config();
    config["identification"] = serde_json::json!({
        "manufacturer": "Machine-tool lab",
        "serial_number": "TJ-0001",
        "product_instance_uri": "urn:example-lab:trijoint:TJ-0001",
        "year_of_construction": 2004
    });
    let dir = tempfile::tempdir().expect("tempdir");
    let users = users_file(dir.path(), OPERATOR, 0o600);
    let mut plc = Plc::configured(
        config,
        "opc.tcp://127.0.0.1:0",
        &["--duration", "300", "--opcua-users", users.to_str().expect("utf-8")],
    );
    let machinery = || client(&python, &["machinery", &plc.url, "trijoint"]);
    let out = machinery();
    let namespaces = out["namespaces"].as_array().expect("namespaces");
    for uri in [
        "http://opcfoundation.org/UA/DI/",
        "http://opcfoundation.org/UA/IA/",
        "http://opcfoundation.org/UA/Machinery/",
        "urn:pkm-plc",
    ] {
        assert!(namespaces.iter().any(|n| n == uri), "{uri}: {out}");
    }
    assert_eq!(out["machines"], serde_json::json!(["trijoint"]), "{out}");
    assert_eq!(out["identification_type"], "MachineToolIdentificationType", "{out}");
    let di = "http://opcfoundation.org/UA/DI/";
    assert_eq!(
        out["identification"],
        serde_json::json!({
            format!("{di}Manufacturer"): "Machine-tool lab",
            format!("{di}Model"): "TRIJOINT 900H lab model",
            format!("{di}SerialNumber"): "TJ-0001",
            format!("{di}ProductInstanceUri"): "urn:example-lab:trijoint:TJ-0001",
            format!("{di}SoftwareRevision"): format!("pkm-plc {}", env!("CARGO_PKG_VERSION")),
            "http://opcfoundation.org/UA/Machinery/YearOfConstruction": 2004,
        }),
        "{out}"
    );
    assert_eq!(
        out["building_blocks"],
        serde_json::json!(["Identification", "MachineryItemState", "MachineryOperationMode"]),
        "{out}"
    );
    for (machine, ty) in [
        ("MachineryItemState", "MachineryItemState_StateMachineType"),
        ("MachineryOperationMode", "MachineryOperationModeStateMachineType"),
    ] {
        assert_eq!(out[machine]["type"], ty, "{out}");
        // CurrentState's Id is the state of the type, in Machinery's namespace.
        assert_eq!(out[machine]["id"], out[machine]["current"], "{out}");
        assert_eq!(
            out[machine]["id_namespace"], "http://opcfoundation.org/UA/Machinery/",
            "{out}"
        );
    }
    // Referencing takes 40 s: the run is in INIT, or READY on a machine slow to get here.
    let together = &out["together"];
    assert!(
        [
            serde_json::json!(["INIT", "Executing", "Setup"]),
            serde_json::json!(["READY", "NotExecuting", "Setup"]),
        ]
        .contains(together),
        "{out}"
    );
    assert_eq!(
        out["MachineryItemState"]["number"],
        if together[0] == "INIT" { 3 } else { 2 }
    );
    assert_eq!(out["MachineryOperationMode"]["number"], 2, "{out}");
    // STOP: out of service, in no mode; the acknowledgement: referencing again.
    let call = |steps: &[&str]| client_steps(&python, "call", &plc.url, &OPERATOR_LOGIN, steps);
    let _ = call(&["Stop", "wait=ERROR"]);
    let out = machinery();
    assert_eq!(
        out["together"],
        serde_json::json!(["ERROR", "OutOfService", "None"]),
        "{out}"
    );
    assert_eq!(out["MachineryItemState"]["number"], 1, "{out}");
    assert_eq!(out["MachineryOperationMode"]["number"], 0, "{out}");
    let _ = call(&["Acknowledge", "wait=INIT"]);
    let out = machinery();
    assert_eq!(
        out["together"],
        serde_json::json!(["INIT", "Executing", "Setup"]),
        "{out}"
    );
    assert!(plc.run.terminate().success(), "{}", plc.log());
}

/// A job the operator's screen refuses raises `JobRefused` (a DiscreteAlarmType, severity 300)
/// with the screen's why; a user acknowledges it, which the PLC has nothing to do with.
#[test]
fn a_job_the_screen_refuses_raises_job_refused() {
    let Some(python) = python_or_skip("opcua::a_job_the_screen_refuses_raises_job_refused") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let users = users_file(dir.path(), OPERATOR, 0o600);
    let mut plc = Plc::start(&[
        "--duration",
        "300",
        "--hmi",
        "127.0.0.1:0",
        "--opcua-users",
        users.to_str().expect("utf-8"),
    ]);
    let screen = plc.screen();
    // Refused whatever the state: in REBOOT or INIT (a busy machine's start may still be in
    // REBOOT) a job waits for READY, in READY this one nests too deep.
    let text = format!("G1 X{}1{} F100", "[".repeat(100), "]".repeat(100));
    common::screen_command(&screen, serde_json::json!({"cmd": "mdi", "text": text}));
    let out = client_steps(
        &python,
        "alarms",
        &plc.url,
        &OPERATOR_LOGIN,
        &[
            "refresh",
            "wait=JobRefused:active",
            "ack=JobRefused",
            "wait=JobRefused:acked",
        ],
    );
    assert!(
        step_outcomes(&out).iter().all(|(_, s)| s == "Good"),
        "{out}\n{}",
        plc.log()
    );
    let seen = condition_events(&out, "JobRefused");
    assert!(seen.len() >= 2, "{out}");
    let (active, acked, retain, message) = &seen[0];
    assert!(*active && !acked && *retain, "{out}");
    assert!(message.starts_with("job refused (screen 127.0.0.1:"), "{message}");
    let why = message.split_once("): ").map(|(_, w)| w).unwrap_or_default();
    assert!(
        ["REBOOT", "INIT"]
            .iter()
            .any(|state| why == format!("a job runs from READY: the machine is {state}"))
            || why.contains("nests deeper than 64 levels"),
        "{message}"
    );
    assert_eq!(seen.last().map(|e| (e.0, e.1)), Some((true, true)), "{out}");
    let event = first_event(&out, "JobRefused");
    assert_eq!(event["type"], "DiscreteAlarmType", "{event}");
    assert_eq!(event["severity"], 300, "{event}");
    // The PLC was not acknowledged: it was in no ERROR to leave.
    let log = plc.log();
    assert!(
        log.contains("OPC UA: user \"operator\" acknowledged the condition JobRefused"),
        "{log}"
    );
    assert!(!log.contains("Acknowledge: the error acknowledged"), "{log}");
    assert!(plc.run.terminate().success(), "{}", plc.log());
}

/// A task class that overruns its cycle raises `CycleTime` (a SystemDiagnosticAlarmType, severity
/// 700) naming the class and its counters, and clears it a second after the last overrun.
#[test]
fn overruns_raise_the_cycle_time_condition_and_it_clears() {
    let name = "opcua::overruns_raise_the_cycle_time_condition_and_it_clears";
    let Some(python) = python_or_skip(name) else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    // The runtime's self-test: the fast class burns 25 ms of its 10 ms cycle once in 200
    // cycles (every 2 s), logging the overrun rather than stopping. Its cyclic thread runs at
    // normal priority: burning 25 ms at SCHED_FIFO took a core from the real-time tests beside
    // it (a TRIJOINT over Modbus, 16.7 ms past its deadline in CI).
    let config = dir.path().join("selftest.json");
    std::fs::write(
        &config,
        r#"{"timing": {"realtime_priority": 0, "lock_memory": false},
            "task_classes": [
            {"name": "fast", "cycle_us": 10000, "tolerance_us": 5000, "priority": 1, "on_violation": "log",
             "programs": [{"program": "selftest.producer", "params": {"burn_us": 25000, "burn_every": 200}}]},
            {"name": "main", "cycle_us": 50000, "tolerance_us": 50000, "priority": 2,
             "programs": [{"program": "selftest.consumer"}]}
        ]}"#,
    )
    .expect("config");
    let mut command = common::pkm_command();
    command
        .args([
            "run",
            "--hmi",
            "none",
            "--opcua",
            "opc.tcp://127.0.0.1:0",
            "--duration",
            "300",
        ])
        .args(["--config", config.to_str().expect("utf-8")])
        .env("RUST_LOG", "info");
    let (mut run, announced) = common::Logged::start(command, "OPC UA server at ", Duration::from_secs(60));
    let port = announced.rsplit(':').next().unwrap_or_default().trim_end_matches('/');
    let url = format!("opc.tcp://127.0.0.1:{port}/");
    let out = client(
        &python,
        &[
            "alarms",
            &url,
            "runtime",
            "refresh",
            "wait=CycleTime:active",
            "wait=CycleTime:inactive",
        ],
    );
    assert!(step_outcomes(&out).iter().all(|(_, s)| s == "Good"), "{out}");
    // (A busy machine may have overrun before the client came: the refresh then shows that
    // condition, cleared and not acknowledged, first.)
    let seen = condition_events(&out, "CycleTime");
    let (_, acked, _, message) = seen.iter().find(|(active, ..)| *active).expect("an active CycleTime");
    assert!(!acked, "{out}");
    assert!(message.starts_with("task class fast: "), "{message}");
    assert!(message.contains(" overrun(s)"), "{message}");
    assert!(
        seen.iter()
            .any(|(active, _, _, m)| !active && m == "no new overrun or cycle time violation for a second"),
        "{out}"
    );
    let event = first_event(&out, "CycleTime");
    assert_eq!(event["type"], "SystemDiagnosticAlarmType", "{event}");
    assert_eq!(event["severity"], 700, "{event}");
    assert!(run.terminate().success(), "{}", run.log());
}

/// Runs the node-opcua client script with `args`; its last stdout line as JSON.
fn node_client(mut node: Command, args: &[&str]) -> Json {
    node.arg(format!(
        "{}/tests/interop/opcua_node_client.js",
        env!("CARGO_MANIFEST_DIR")
    ));
    last_json(node, args)
}

/// node-opcua's client (Node-RED's stack) connects with its defaults, which refuse an endpoint
/// the server does not advertise (`endpointMustExist`): on loopback unsecured, with and without
/// the root's `/`, and beyond it through another address than the one the server was started
/// on, signed and encrypted, its certificate trusted as an administrator would.
#[test]
fn node_opcua_connects_with_its_defaults_on_loopback_and_through_another_address() {
    let name = "opcua::node_opcua_connects_with_its_defaults_on_loopback_and_through_another_address";
    if let Err(why) = common::node_interop() {
        common::skip(name, &why);
        return;
    }
    let node = || common::node_interop().expect("made above");
    let mut plc = Plc::start(&["--duration", "300"]);
    let bare = plc.url.trim_end_matches('/').to_string();
    for url in [plc.url.as_str(), bare.as_str()] {
        let out = node_client(node(), &["read", url, "trijoint"]);
        assert!(matches!(out["state"].as_str(), Some("INIT" | "READY")), "{out}");
        // The Machinery view, by browse path through the companions' namespaces.
        assert_eq!(out["machinery"]["model"], "TRIJOINT 900H lab model", "{out}");
        assert!(
            matches!(
                out["machinery"]["item_state"].as_str(),
                Some("Executing" | "NotExecuting")
            ),
            "{out}"
        );
        // Every endpoint is advertised at the URL the client used.
        for e in out["endpoints"].as_array().expect("endpoints") {
            assert_eq!(e[0], url, "{out}");
        }
        // The machine tool (OPC 40501-1) by browse paths through its namespaces, typed.
        let mt = "http://opcfoundation.org/UA/MachineTool/";
        let view = &out["machine_tool"];
        for (block, ty) in [
            ("machine", "MachineToolType"),
            ("identification", "MachineToolIdentificationType"),
            ("monitoring", "MonitoringType"),
            ("channel", "ChannelMonitoringType"),
            ("production", "ProductionType"),
            ("active_program", "ProductionActiveProgramType"),
            ("notification", "NotificationType"),
            ("equipment", "EquipmentType"),
        ] {
            assert_eq!(view["types"][block], format!("{mt}:{ty}"), "{block}: {out}");
        }
        // Setup while referencing, Manual once READY; the channel waits (Reset).
        assert!(
            matches!(view["values"]["operation_mode"].as_i64(), Some(0 | 2)),
            "{out}"
        );
        assert_eq!(view["values"]["channel_state"], 2, "{out}");
        assert_eq!(view["values"]["feed_override"], 100, "{out}");
        assert_eq!(view["values"]["program_state"], "Initializing", "{out}");
    }
    let status = plc.run.terminate();
    assert!(status.success(), "{status}");

    let dir = tempfile::tempdir().expect("tempdir");
    let path = |name: &str| dir.path().join(name).to_str().expect("utf-8").to_string();
    users_file(dir.path(), OPERATOR, 0o600);
    let pki = path("pki");
    let mut plc = Plc::serving(
        "opc.tcp://0.0.0.0:0",
        &[
            "--duration",
            "300",
            "--opcua-users",
            &path("users.json"),
            "--opcua-pki",
            &pki,
        ],
    );
    let via = plc.url.replace("127.0.0.1", "127.0.0.2");
    let out = node_client(
        node(),
        &["read", &via, "trijoint", "--secure", &path("client"), "--pki", &pki],
    );
    assert!(matches!(out["state"].as_str(), Some("INIT" | "READY")), "{out}");
    assert_eq!(out["untrusted_first"], true, "{out}");
    for e in out["endpoints"].as_array().expect("endpoints") {
        assert_eq!(e[0], via.as_str(), "{out}");
    }
    let status = plc.run.terminate();
    assert!(status.success(), "{status}");
}

#[test]
fn a_malformed_hello_is_refused_and_the_server_serves_on() {
    let plc = Plc::start(&["--duration", "30"]);
    let addr = plc
        .url
        .trim_start_matches("opc.tcp://")
        .trim_end_matches('/')
        .to_string();
    let attacks: [&[u8]; 3] = [
        // Not OPC UA at all.
        b"GET / HTTP/1.1\r\nHost: x\r\n\r\n",
        // A hello that claims 4 GiB.
        b"HELF\xff\xff\xff\xff\x00\x00\x00\x00",
        // A hello whose fields end early, then garbage.
        b"HELF\x20\x00\x00\x00\x00\x00\x00\x00\xff\xff\xff\xff\x01\x02\x03\x04\x05\x06\x07\x08",
    ];
    for attack in attacks {
        let mut s = std::net::TcpStream::connect(&addr).expect("connects");
        s.set_read_timeout(Some(Duration::from_secs(10))).expect("timeout");
        s.write_all(attack).expect("sends");
        let started = Instant::now();
        let mut answer = Vec::new();
        let _ = s.read_to_end(&mut answer);
        assert!(
            started.elapsed() < Duration::from_secs(8),
            "the connection was closed ({} bytes answered)",
            answer.len()
        );
        // Either closed at once or an ERR message first.
        assert!(answer.is_empty() || answer.starts_with(b"ERRF"), "{answer:?}");
    }
    // The server still serves a proper client, and the machine ran on.
    let mut proper = std::net::TcpStream::connect(&addr).expect("connects");
    proper.set_read_timeout(Some(Duration::from_secs(10))).expect("timeout");
    proper.write_all(&hello(&plc.url)).expect("hello");
    let mut ack = [0u8; 8];
    proper.read_exact(&mut ack).expect("an acknowledge");
    assert_eq!(&ack[..4], b"ACKF", "{ack:?}");
    let log = plc.log();
    assert!(!log.contains("panic"), "{log}");
    assert!(log.contains("t=0.050 s: INIT"), "{log}");
}

/// Each machine's server has a certificate of its own, in a store of its own (by default one
/// directory per machine): its common name and application URI name the machine, so a client
/// trusted for one machine is not trusted for another. A store named for one machine and given
/// to another is refused with why, before anything runs.
#[test]
fn each_machine_has_a_certificate_of_its_own() {
    let data = tempfile::tempdir().expect("tempdir");
    let run = |machine: &str, extra: &[&str]| {
        common::pkm_command()
            .args([
                "run",
                "--hmi",
                "none",
                "--opcua",
                "opc.tcp://127.0.0.1:0",
                "--duration",
                "0.5",
            ])
            .args(["--machine", machine])
            .args(extra)
            .env("XDG_DATA_HOME", data.path())
            .env("RUST_LOG", "warn")
            .output()
            .expect("the binary runs")
    };
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .unwrap_or_default();
    let stores = data.path().join("pkm-plc/opcua-pki");
    for machine in ["trijoint", "ox-x"] {
        let o = run(machine, &[]);
        assert!(o.status.success(), "{machine}: {}", common::stderr(&o));
        let der = std::fs::read(stores.join(machine).join("own/cert.der")).expect("its certificate");
        let cert = opcua::crypto::X509::from_der(&der).expect("a certificate");
        assert_eq!(
            cert.common_name().expect("a common name"),
            format!("CN=pkm-plc ({machine})")
        );
        let uri = format!(
            "urn:{}:pkm-plc:{machine}",
            if host.is_empty() { "localhost" } else { &host }
        );
        assert!(cert.is_application_uri_valid(&uri).is_ok(), "{machine}: not {uri}");
        // Started again, the machine keeps its certificate.
        let o = run(machine, &[]);
        assert!(o.status.success(), "{machine}: {}", common::stderr(&o));
        assert_eq!(
            std::fs::read(stores.join(machine).join("own/cert.der")).expect("kept"),
            der
        );
    }
    // The TRIJOINT's store given to the O-X glide.
    let trijoint = stores.join("trijoint");
    let o = run("ox-x", &["--opcua-pki", trijoint.to_str().expect("utf-8")]);
    assert_eq!(o.status.code(), Some(2), "{}", common::stderr(&o));
    let err = common::stderr(&o);
    assert!(
        err.contains("the certificate there was made for another server")
            && err.contains("pkm-plc (trijoint)")
            && err.contains(":pkm-plc:ox-x: give this machine a certificate store of its own (--opcua-pki DIR)"),
        "{err}"
    );
}

/// A well-formed OPC UA hello for `url` (OPC UA Part 6, 7.1.2.3).
fn hello(url: &str) -> Vec<u8> {
    let mut body = Vec::new();
    for v in [0u32, 65_536, 65_536, 0, 0] {
        body.extend_from_slice(&v.to_le_bytes());
    }
    body.extend_from_slice(&(url.len() as i32).to_le_bytes());
    body.extend_from_slice(url.as_bytes());
    let mut m = b"HELF".to_vec();
    m.extend_from_slice(&((body.len() + 8) as u32).to_le_bytes());
    m.extend_from_slice(&body);
    m
}

#[test]
fn serving_beyond_loopback_needs_users_and_the_options_are_checked_before_anything_runs() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = |args: &[&str]| {
        let o = common::pkm_command()
            .args(["run", "--hmi", "none", "--duration", "1"])
            .args(args)
            .env("RUST_LOG", "warn")
            .output()
            .expect("runs");
        (o.status.code(), common::stderr(&o))
    };
    let (code, err) = run(&["--opcua", "opc.tcp://0.0.0.0:0"]);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains(
            "--opcua 0.0.0.0:0: serving OPC UA beyond this computer needs users who may command (--opcua-users FILE)"
        ),
        "{err}"
    );
    let (code, err) = run(&["--virtual", "--opcua", "opc.tcp://127.0.0.1:0"]);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("--opcua serves OPC UA in real time or in a paced simulation (--virtual --pace X)"),
        "{err}"
    );
    let (code, err) = run(&["--opcua", "http://127.0.0.1:4840"]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("an OPC UA endpoint is opc.tcp://HOST:PORT"), "{err}");
    // Others may read it.
    let users = users_file(dir.path(), OPERATOR, 0o644);
    let users = users.to_str().expect("utf-8");
    let (code, err) = run(&["--opcua", "opc.tcp://127.0.0.1:0", "--opcua-users", users]);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("it holds passwords and others may read it (mode 644): chmod 600"),
        "{err}"
    );
    let (code, err) = run(&["--opcua-users", users]);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("--opcua-users and --opcua-pki configure the OPC UA server, which is off (--opcua none, or PKM_PLC_OPCUA=none in the environment)"),
        "{err}"
    );
    // A port someone has: an address given is exit 2 with why.
    let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("a port");
    let at = format!("opc.tcp://{}", taken.local_addr().expect("addr"));
    let (code, err) = run(&["--opcua", &at]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("OPC UA: cannot listen on 127.0.0.1:"), "{err}");
    assert!(err.contains("or run without OPC UA with --opcua none"), "{err}");
}

/// A relay on a free loopback port to the server at `url`, keeping every byte clients send
/// through it: its URL and what was sent.
fn recording_relay(url: &str) -> (String, std::sync::Arc<std::sync::Mutex<Vec<u8>>>) {
    let target = url.trim_start_matches("opc.tcp://").trim_end_matches('/').to_string();
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("a free port");
    let port = listener.local_addr().expect("its address").port();
    let sent = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let kept = std::sync::Arc::clone(&sent);
    std::thread::spawn(move || {
        for client in listener.incoming().map_while(Result::ok) {
            let Ok(server) = std::net::TcpStream::connect(&target) else {
                continue;
            };
            let (mut from_client, mut to_server) = (
                client.try_clone().expect("a clone"),
                server.try_clone().expect("a clone"),
            );
            let (mut from_server, mut to_client) = (server, client);
            let kept = std::sync::Arc::clone(&kept);
            std::thread::spawn(move || {
                let mut buffer = [0u8; 16 * 1024];
                while let Ok(n @ 1..) = from_client.read(&mut buffer) {
                    kept.lock().expect("the record").extend_from_slice(&buffer[..n]);
                    if to_server.write_all(&buffer[..n]).is_err() {
                        break;
                    }
                }
                let _ = to_server.shutdown(std::net::Shutdown::Both);
            });
            std::thread::spawn(move || {
                let _ = std::io::copy(&mut from_server, &mut to_client);
                let _ = to_client.shutdown(std::net::Shutdown::Both);
            });
        }
    });
    (format!("opc.tcp://127.0.0.1:{port}/"), sent)
}

/// No password crosses the unsecured endpoint readable: its user token policy names a security
/// policy (Basic256Sha256), so asyncua encrypts the password with the server's key — it sent it
/// in clear before — and the bytes it sent hold no trace of it; a password sent in clear anyway
/// (a client that ignores the policy) is refused, and no session opens.
#[test]
fn a_password_never_crosses_the_unsecured_endpoint_in_clear() {
    let Some(python) = python_or_skip("opcua::a_password_never_crosses_the_unsecured_endpoint_in_clear") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let users = users_file(dir.path(), OPERATOR, 0o600);
    let plc = Plc::start(&["--duration", "120", "--opcua-users", users.to_str().expect("utf-8")]);
    let (relay, sent) = recording_relay(&plc.url);
    let out = client_steps(&python, "call", &relay, &OPERATOR_LOGIN, &["Stop"]);
    assert_eq!(out["steps"][0]["status"], "Good", "the operator commanded: {out}");
    let password = OPERATOR_LOGIN[3].as_bytes();
    let bytes = sent.lock().expect("the record").clone();
    assert!(
        bytes.len() > 1000,
        "the relay carried the session: {} bytes",
        bytes.len()
    );
    assert!(
        !bytes.windows(password.len()).any(|w| w == password),
        "the password crossed in clear"
    );
    // In clear anyway: refused.
    let mut login = OPERATOR_LOGIN.to_vec();
    login.extend(["--clear", "yes"]);
    let refused = client_steps(&python, "call", &relay, &login, &["Stop"]);
    assert_eq!(refused["refused"], "BadIdentityTokenInvalid", "{refused}");
}

/// The reconnecting recipe of docs/opcua.md (`examples/opcua/reconnect.py`, asyncua) goes on by
/// itself through a server restart: the PLC stops (SIGTERM: its shutdown notice) and starts
/// again on the same port, and the recipe's subscription delivers the new run's states.
#[test]
fn the_asyncua_recipe_reconnects_after_a_server_restart() {
    let Some(python) = python_or_skip("opcua::the_asyncua_recipe_reconnects_after_a_server_restart") else {
        return;
    };
    let mut first = Plc::start(&["--duration", "120"]);
    let url = first.url.clone();
    let recipe = format!("{}/examples/opcua/reconnect.py", env!("CARGO_MANIFEST_DIR"));
    let watcher = Command::new(&python)
        .args([recipe.as_str(), url.as_str(), "trijoint", "30"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("the recipe runs");
    // Watching the first run; then it stops, and another starts on the same port.
    std::thread::sleep(Duration::from_secs(6));
    assert!(first.run.terminate().success(), "{}", first.run.log());
    std::thread::sleep(Duration::from_secs(1));
    let second = Plc::serving(&url, &["--duration", "120"]);
    let o = watcher.wait_with_output().expect("the recipe ends");
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&o.stderr));
    let out: Json =
        serde_json::from_str(stdout.lines().last().unwrap_or_default()).unwrap_or_else(|e| panic!("{e}: {stdout}"));
    assert!(out["reconnects"].as_u64() >= Some(1), "{out}");
    assert!(
        out["after_reconnect"].as_u64() >= Some(1),
        "the new run's states after the reconnect: {out}\n{}",
        second.run.log()
    );
}

/// The Machine Tools view (OPC 40501-1) of `url`'s `machine`, as umati reads it.
fn machine_tool_view(python: &Path, url: &str, machine: &str) -> Json {
    client(python, &["machine_tool", url, machine])
}

/// Sends the screen at `screen` (`http://…/`) the MDI job `text` and waits for what became of
/// it: the screen's reply, `job` (made, loaded and started) or `refused`.
fn screen_mdi(screen: &str, text: &str) -> Json {
    use crate::screen_ws::{next, reply, send};
    common::on_screen(screen, async |ws| {
        // The screen greets every page first.
        let hello = next(ws, Duration::from_secs(30)).await;
        assert_eq!(hello["type"], "hello", "{hello}");
        send(ws, serde_json::json!({"cmd": "mdi", "text": text})).await;
        let planning = reply(ws, Duration::from_secs(30)).await;
        assert_eq!(planning["type"], "planning", "{planning}");
        reply(ws, Duration::from_secs(60)).await
    })
}

/// Reads the Machine Tools view every half second until `done` holds (at most `within`): the
/// view then.
fn view_until(python: &Path, url: &str, within: Duration, done: impl Fn(&Json) -> bool) -> Json {
    let start = Instant::now();
    loop {
        let view = machine_tool_view(python, url, "ox-x");
        if done(&view) || start.elapsed() > within {
            return view;
        }
        std::thread::sleep(Duration::from_millis(500));
    }
}

/// OPC 40501-1 (Machine Tools) as umati reads it, on the O-X glide with a tool table of two
/// tools and a program that changes to tool 1 by hand: the machine's object is a
/// `MachineToolType` whose every Mandatory child — down the declarations' hierarchy, and in
/// every channel, tool and job — is there with its namespace, node class, type definition and
/// data type, checked by asyncua against the type definitions the server serves from the
/// published NodeSet; no object of the server's goes untyped. Then the view follows the run:
/// Manual and Reset in READY with the program loaded and Initializing and both tools in `Equipment/Tools`; loaded and
/// started by the operator, Automatic, with a `ToolChange` prognosis naming tool 1 and its
/// comment predicted from the plan within the first move's 10 s; at the M6 the channel
/// Interrupted and the change due; confirmed on the screen, the program and its job
/// Ended with one run completed and the prognosis gone; a screen MDI job a new load, run and
/// ended, and so still after a screen job refused. The operator's Stop reaches a subscriber of
/// `Notification/Messages`.
#[test]
fn the_machine_tool_view_is_whole_by_its_types_and_follows_a_program_with_a_manual_tool_change() {
    use std::io::BufRead;
    let name = "opcua::the_machine_tool_view_is_whole_by_its_types_and_follows_a_program_with_a_manual_tool_change";
    let Some(python) = python_or_skip(name) else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let path = |name: &str| dir.path().join(name).to_str().expect("utf-8").to_string();
    let config = common::read_json(&common::ox_config(dir.path(), true, |_| {}));
    std::fs::write(path("tool.tbl"), "T1 P1 Z10 ;6 mm end mill\nT2 P2 Z20 ;3 mm drill\n").expect("the table");
    std::fs::create_dir(path("programs")).expect("programs");
    // Ten seconds of moving before the change, so that it is seen ahead: each look at the view
    // starts an asyncua client of its own, and beside the suite and `stress-ng --cpu 2` the first
    // look came after a move of 3 s had ended.
    std::fs::write(path("programs/tools.ngc"), "G1 X3 F18\nT1 M6\nG1 X0 F600\nM2\n").expect("the program");
    users_file(dir.path(), OPERATOR, 0o600);
    let plc = Plc::configured(
        config,
        "opc.tcp://127.0.0.1:0",
        &[
            "--hmi",
            "127.0.0.1:0",
            "--joystick",
            "none",
            "--duration",
            "300",
            "--programs",
            &path("programs"),
            "--tool-table",
            &path("tool.tbl"),
            "--opcua-users",
            &path("users.json"),
        ],
    );
    let screen = plc.screen();
    plc.run.wait_for_state(0, "READY", Duration::from_secs(120));
    let mt = "http://opcfoundation.org/UA/MachineTool/";

    let checked = client(&python, &["typecheck", &plc.url, "ns=2;s=ox-x"]);
    assert_eq!(checked["type"], format!("{mt}:MachineToolType"), "{checked}");
    for list in ["missing", "wrong", "untyped"] {
        assert_eq!(checked[list], serde_json::json!([]), "{list}: {checked}");
    }
    let declarations = checked["declarations"].as_u64().unwrap_or_default();
    assert!(declarations >= 60, "{declarations} declarations checked: {checked}");

    let before = machine_tool_view(&python, &plc.url, "ox-x");
    assert_eq!(before["operation_mode"], 0, "Manual: {before}");
    assert_eq!(
        (before["channel_state"].clone(), before["channel_mode"].clone()),
        (2.into(), 2.into()),
        "Reset, JogManual: {before}"
    );
    // The library's first program is loaded, not started.
    assert!(
        before["program"].as_str().is_some_and(|p| p.ends_with("tools.ngc")),
        "{before}"
    );
    assert_eq!(before["program_state"], "Initializing", "{before}");
    assert_eq!(
        (before["runs_completed"].clone(), before["runs_planned"].clone()),
        (0.into(), 1.into()),
        "{before}"
    );
    assert_eq!(
        before["tools"],
        serde_json::json!({"T1": {"name": "6 mm end mill", "number": 1}, "T2": {"name": "3 mm drill", "number": 2}}),
        "{before}"
    );
    assert_eq!(before["prognoses"], serde_json::json!({}), "{before}");

    let mut messages = Command::new(&python)
        .arg(format!("{}/tests/interop/opcua_client.py", env!("CARGO_MANIFEST_DIR")))
        .args(["messages", &plc.url, "ox-x", "90"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("a subscriber");
    let mut said = std::io::BufReader::new(messages.stdout.take().expect("stdout"));
    let mut line = String::new();
    said.read_line(&mut line).expect("subscribed");
    assert_eq!(line.trim(), "subscribed");

    let mut start = vec!["call", &plc.url, "ox-x"];
    start.extend_from_slice(&OPERATOR_LOGIN);
    start.extend_from_slice(&["Load=1", "Start"]);
    let started = client(&python, &start);
    assert_eq!(started["steps"][0]["status"], "Good", "{started}");
    assert_eq!(started["steps"][1]["status"], "Good", "{started}");
    // While the first move runs, the change is ahead: predicted from the plan's time line.
    let ahead = view_until(&python, &plc.url, Duration::from_secs(60), |v| {
        v["prognoses"].get("ToolChange").is_some() || v["channel_state"] == 1
    });
    let predicted = ahead["prognoses"]["ToolChange"]["PredictedTime"].as_f64();
    let read_at = ahead["read_at"].as_f64().unwrap_or_default();
    assert_eq!(ahead["channel_state"], 0, "Active, the change ahead: {ahead}");
    assert!(
        predicted.is_some_and(|p| p > read_at && p < read_at + 11.0),
        "a change predicted within the first move's 10 s: {ahead}"
    );
    assert_eq!(ahead["prognoses"]["ToolChange"]["ToolIdentifier"], "T1", "{ahead}");
    let due = view_until(&python, &plc.url, Duration::from_secs(90), |v| v["channel_state"] == 1);
    let change = &due["prognoses"]["ToolChange"];
    assert_eq!(change["ToolIdentifier"], "T1", "{due}");
    assert_eq!(change["ToolName"], "6 mm end mill", "{due}");
    assert_eq!(change["Location"], "spindle (manual change)", "{due}");
    assert_eq!(due["operation_mode"], 1, "Automatic: {due}");
    assert_eq!(
        (due["channel_state"].clone(), due["channel_mode"].clone()),
        (1.into(), 0.into()),
        "Interrupted, Automatic: {due}"
    );
    assert_eq!(due["program_state"], "Interrupted", "{due}");
    assert!(
        due["program"].as_str().is_some_and(|p| p.ends_with("tools.ngc")),
        "{due}"
    );

    common::screen_command(
        &screen,
        serde_json::json!({"cmd": "tool_changed", "tool": 1, "change": 1}),
    );
    let ended = view_until(&python, &plc.url, Duration::from_secs(60), |v| {
        v["program_state"] == "Ended" && v["channel_state"] == 2
    });
    assert_eq!(ended["program_state"], "Ended", "{ended}\n{}", plc.log());
    assert_eq!(ended["job_state"], "Ended", "{ended}");
    assert_eq!(ended["runs_completed"], 1, "{ended}");
    assert_eq!(ended["runs_planned"], 1, "{ended}");
    assert_eq!(ended["prognoses"], serde_json::json!({}), "{ended}");

    // A screen job is a new load: an MDI line, made, started, ended — a job of one run.
    let made = screen_mdi(&screen, "G1 X1 F600");
    assert_eq!((&made["type"], &made["file"]), (&"job".into(), &"MDI".into()), "{made}");
    let mdi = view_until(&python, &plc.url, Duration::from_secs(60), |v| {
        v["program"] == "MDI" && v["program_state"] == "Ended"
    });
    assert_eq!(
        (&mdi["program"], &mdi["program_state"], &mdi["runs_completed"]),
        (&"MDI".into(), &"Ended".into(), &1.into()),
        "{mdi}"
    );
    // One the screen refuses loads nothing: the MDI stays the active program, ended, its run
    // counted (a refusal was taken for a new load, the runs counted from 0 again, and the
    // program named "job 2").
    let deep = format!("G1 X{}1{} F100", "[".repeat(100), "]".repeat(100));
    let refused = screen_mdi(&screen, &deep);
    assert_eq!(
        (&refused["type"], &refused["job"]),
        (&"refused".into(), &true.into()),
        "{refused}"
    );
    let after = machine_tool_view(&python, &plc.url, "ox-x");
    assert_eq!(
        (
            &after["program"],
            &after["program_state"],
            &after["runs_completed"],
            &after["runs_planned"]
        ),
        (&"MDI".into(), &"Ended".into(), &1.into(), &1.into()),
        "{after}"
    );

    let mut stop = vec!["call", &plc.url, "ox-x"];
    stop.extend_from_slice(&OPERATOR_LOGIN);
    stop.extend_from_slice(&["Stop", "wait=ERROR"]);
    let stopped = client(&python, &stop);
    assert_eq!(stopped["steps"][0]["status"], "Good", "{stopped}");
    // The Stop alarm comes to the subscriber of Messages (it ends on its own after 90 s).
    let mut events = Vec::new();
    let came = loop {
        line.clear();
        if said.read_line(&mut line).unwrap_or(0) == 0 {
            break false;
        }
        let event: Json = serde_json::from_str(line.trim()).unwrap_or_default();
        events.push(event.clone());
        if event["name"] == "Stop" && event["active"] == true {
            break true;
        }
    };
    let _ = messages.kill();
    let _ = messages.wait();
    assert!(came, "no active Stop at Notification/Messages: {events:?}");
    eprintln!("machine tool view: {declarations} mandatory declarations checked; READY {before}");
}
