//! Traces: round trip, tampering, malformed files, configuration checks, golden traces.

use crate::common;

use std::path::Path;

use common::{pkm, record_trace as record, stderr, stdout};

#[test]
fn a_recorded_run_replays_identically_and_a_tampered_one_names_cycle_and_variable() {
    let dir = tempfile::tempdir().expect("tempdir");
    let trace = record(
        dir.path(),
        "t.jsonl",
        3,
        r#"[{"at_ms": 1000, "input": "BUTTON_STOP", "value": true}]"#,
    );
    let path = trace.to_str().expect("utf-8");
    let o = pkm(&["replay", path]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(
        stdout(&o).starts_with(&format!("{path}: identical: 390 records over 3.0 s of recorded time")),
        "{}",
        stdout(&o)
    );

    // Change one output of one cycle: the replay names that line, cycle and variable.
    let text = std::fs::read_to_string(&trace).expect("trace");
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let (n, line) = lines
        .iter()
        .enumerate()
        .find(|(_, l)| {
            l.contains(r#""task":"fast""#) && l.contains(r#""velocity_left_set":"#) && l.contains(r#""t_us":500000"#)
        })
        .map(|(n, l)| (n, l.clone()))
        .expect("a fast record at 0.5 s that sets velocity_left_set");
    let record: serde_json::Value = serde_json::from_str(&line).expect("json");
    let recorded = record["out"]["velocity_left_set"].as_i64().expect("INT");
    let mut tampered = record.clone();
    tampered["out"]["velocity_left_set"] = serde_json::json!(recorded + 1);
    lines[n] = tampered.to_string();
    std::fs::write(&trace, lines.join("\n") + "\n").expect("write");
    let o = pkm(&["replay", path]);
    assert_eq!(o.status.code(), Some(1));
    assert_eq!(
        stderr(&o),
        format!(
            "error: {path}: replay differs at line {} (task fast, cycle 50, t = 0.500 s): velocity_left_set recorded {}, replayed {recorded}\n",
            n + 1,
            recorded + 1
        )
    );
}

#[test]
fn of_two_outputs_that_differ_in_one_cycle_the_first_in_the_headers_order_is_reported() {
    let dir = tempfile::tempdir().expect("tempdir");
    let trace = record(dir.path(), "t.jsonl", 1, "[]");
    let path = trace.to_str().expect("utf-8");
    // JOINT1_POSITION (REAL) comes before counts_right (DINT) among the fast class's outputs;
    // the replay compares the DINTs before the REALs, yet names JOINT1_POSITION.
    let text = std::fs::read_to_string(&trace).expect("trace");
    let header: serde_json::Value = serde_json::from_str(text.lines().next().expect("header")).expect("json");
    let outputs: Vec<&str> = header["task_classes"]
        .as_array()
        .and_then(|c| c.iter().find(|c| c["name"] == "fast"))
        .and_then(|c| c["outputs"].as_array())
        .expect("fast outputs")
        .iter()
        .filter_map(|o| o.as_str())
        .collect();
    let at = |name: &str| outputs.iter().position(|o| *o == name).expect(name);
    assert!(at("JOINT1_POSITION") < at("counts_right"));
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let n = lines
        .iter()
        .position(|l| l.contains(r#""task":"fast""#) && l.contains(r#""t_us":500000"#))
        .expect("a fast record at 0.5 s");
    let mut tampered: serde_json::Value = serde_json::from_str(&lines[n]).expect("json");
    tampered["out"]["counts_right"] = serde_json::json!(-7);
    tampered["out"]["JOINT1_POSITION"] = serde_json::json!(12345.5);
    lines[n] = tampered.to_string();
    std::fs::write(&trace, lines.join("\n") + "\n").expect("write");
    let o = pkm(&["replay", path]);
    assert_eq!(o.status.code(), Some(1));
    let expected = format!(
        "error: {path}: replay differs at line {} (task fast, cycle 50, t = 0.500 s): JOINT1_POSITION recorded 12345.5, replayed ",
        n + 1
    );
    assert!(stderr(&o).starts_with(&expected), "{}", stderr(&o));
}

#[test]
fn malformed_traces_are_clear_errors_with_line_numbers() {
    let dir = tempfile::tempdir().expect("tempdir");
    let trace = record(dir.path(), "ok.jsonl", 1, "[]");
    let text = std::fs::read_to_string(&trace).expect("trace");
    let header = text.lines().next().expect("header").to_string();
    let good = text.lines().nth(1).expect("record").to_string();
    let check = |name: &str, content: &str, expected: &str| {
        let path = dir.path().join(name);
        std::fs::write(&path, content).expect("write");
        let o = pkm(&["replay", path.to_str().expect("utf-8")]);
        assert_eq!(o.status.code(), Some(2), "{name}: {}", stderr(&o));
        assert_eq!(stderr(&o), format!("error: {}{expected}\n", path.display()), "{name}");
    };
    check("empty.jsonl", "", ": empty trace: no header");
    check(
        "header.jsonl",
        "{\"format\": \"csv\"}\n",
        ":1: bad header: missing field `version` at line 1 column 17",
    );
    check(
        "format.jsonl",
        &header.replace("pkm-plc trace", "other trace"),
        ":1: bad header: format \"other trace\" is not \"pkm-plc trace\"",
    );
    // A record cut right after the opening brace of "in", with a whole one after it: not a
    // crash's cut (that is the last line) but a damaged file.
    let cut = good.find(r#""in":{"#).expect("an in object") + r#""in":{"#.len();
    check(
        "truncated.jsonl",
        &format!("{header}\n{}\n{good}\n", &good[..cut]),
        &format!(":2: malformed record: EOF while parsing an object at line 1 column {cut}"),
    );
    check(
        "unknown-var.jsonl",
        &format!("{header}\n{}\n", good.replace("\"BUTTON_STOP\"", "\"BUTTON_GO\"")),
        ":2: variable \"BUTTON_GO\" is not an input of task class \"fast\" in the header",
    );
    check(
        "wrong-type.jsonl",
        &format!(
            "{header}\n{}\n",
            good.replace("\"BUTTON_STOP\":false", "\"BUTTON_STOP\":3")
        ),
        ":2: variable \"BUTTON_STOP\": expected BOOL (true or false), got 3",
    );
    check(
        "task.jsonl",
        &format!(
            "{header}\n{}\n",
            good.replace("\"task\":\"fast\"", "\"task\":\"turbo\"")
        ),
        ":2: unknown task class \"turbo\" (the header has fast, main, spare)",
    );
    let o = pkm(&["replay", "/nonexistent/t.jsonl"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).starts_with("error: /nonexistent/t.jsonl: cannot open: "),
        "{}",
        stderr(&o)
    );
}

#[test]
fn a_trace_from_another_configuration_is_refused_unless_forced() {
    let dir = tempfile::tempdir().expect("tempdir");
    let trace = record(dir.path(), "t.jsonl", 1, "[]");
    let mut config = common::repo_config();
    config["io_map"] = serde_json::json!(concat!(env!("CARGO_MANIFEST_DIR"), "/io-map/trijoint.json"));
    config["task_classes"][2]["tolerance_us"] = serde_json::json!(90000);
    let other = common::write_config(dir.path(), "other.json", &config);
    let args = [
        "replay",
        trace.to_str().expect("utf-8"),
        "--config",
        other.to_str().expect("utf-8"),
    ];
    let o = pkm(&args);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("recorded with another configuration or I/O map"),
        "{}",
        stderr(&o)
    );
    assert!(stderr(&o).contains("use --force to replay anyway"), "{}", stderr(&o));
    let o = pkm(&[args[0], args[1], args[2], args[3], "--force"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(stdout(&o).contains(": identical: "));
}

#[derive(serde::Deserialize)]
struct Golden {
    traces: Vec<GoldenTrace>,
}

#[derive(serde::Deserialize)]
struct GoldenTrace {
    name: String,
    /// The machine whose configuration records and replays it (`--machine`); the repository's
    /// config.json (the TRIJOINT) when left out.
    #[serde(default)]
    machine: Option<String>,
    duration_s: u32,
    events: serde_json::Value,
    /// The NC program it runs (`--program`), if any.
    #[serde(default)]
    program: Option<String>,
}

#[test]
fn golden_traces_replay_identically() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/traces");
    let golden: Golden = serde_json::from_str(&std::fs::read_to_string(dir.join("golden.json")).expect("golden.json"))
        .expect("golden.json");
    let bless = std::env::var_os("PKM_PLC_BLESS").is_some();
    let scratch = tempfile::tempdir().expect("tempdir");
    for g in &golden.traces {
        let trace = dir.join(format!("{}.jsonl.gz", g.name));
        let machine: Vec<&str> = g.machine.iter().flat_map(|m| ["--machine", m.as_str()]).collect();
        if bless {
            let mut run = machine.clone();
            run.extend(g.program.iter().flat_map(|p| ["--program", p.as_str()]));
            let recorded = common::record_machine_trace(
                scratch.path(),
                &format!("{}.jsonl.gz", g.name),
                g.duration_s,
                &g.events.to_string(),
                &run,
            );
            std::fs::copy(recorded, &trace).expect("bless");
        }
        let mut replay = vec!["replay", trace.to_str().expect("utf-8")];
        replay.extend_from_slice(&machine);
        let o = pkm(&replay);
        assert_eq!(o.status.code(), Some(0), "golden trace {}: {}", g.name, stderr(&o));
        // The reviewable form beside it: state transitions and sampled outputs as text.
        let o = pkm(&["trace", "summary", trace.to_str().expect("utf-8")]);
        assert_eq!(o.status.code(), Some(0), "summary of {}: {}", g.name, stderr(&o));
        let summary = String::from_utf8(o.stdout).expect("utf-8");
        let expected = dir.join(format!("{}.expected", g.name));
        if bless {
            std::fs::write(&expected, &summary).expect("bless the expected summary");
        }
        let want = std::fs::read_to_string(&expected)
            .unwrap_or_else(|e| panic!("{}: {e} (PKM_PLC_BLESS=1 writes it)", expected.display()));
        if want != summary {
            let first = want
                .lines()
                .zip(summary.lines())
                .position(|(a, b)| a != b)
                .unwrap_or(want.lines().count().min(summary.lines().count()));
            panic!(
                "{}: the trace's summary differs from the expected one at line {}:\n  expected: {}\n  trace:    {}",
                expected.display(),
                first + 1,
                want.lines().nth(first).unwrap_or("(end)"),
                summary.lines().nth(first).unwrap_or("(end)")
            );
        }
    }
}

#[test]
fn traces_export_to_vcd_and_svg() {
    let dir = tempfile::tempdir().expect("tempdir");
    let trace = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/traces/limit-switch-fault.jsonl.gz");
    let vcd = dir.path().join("t.vcd");
    let o = pkm(&[
        "trace",
        "vcd",
        trace.to_str().expect("utf-8"),
        vcd.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let text = std::fs::read_to_string(&vcd).expect("vcd");
    assert!(
        text.starts_with("$timescale 1 us $end\n$scope module pkm_plc $end\n"),
        "{}",
        &text[..200]
    );
    assert!(text.contains("$var wire 1 $ BUTTON_STOP $end"));
    assert!(text.contains("$var integer 16 "), "INT variables as 16-bit integers");
    assert!(text.contains("\n#45000000\n"), "a timestamp at the fault");
    assert!(
        text.contains("limit_switch_SWITCH_RIGHT_UPPER"),
        "the error reason as a string"
    );

    let svg = dir.path().join("t.svg");
    let o = pkm(&[
        "trace",
        "plot",
        trace.to_str().expect("utf-8"),
        svg.to_str().expect("utf-8"),
        "--vars",
        "TOOL_X,SWITCH_RIGHT_UPPER",
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let text = std::fs::read_to_string(&svg).expect("svg");
    for caption in [
        "TOOL_X",
        "SWITCH_RIGHT_UPPER",
        "state (REBOOT / INIT / READY / MOTION / ERROR)",
    ] {
        assert!(text.contains(&format!("\n{caption}\n</text>")), "panel {caption}");
    }
    let o = pkm(&[
        "trace",
        "plot",
        trace.to_str().expect("utf-8"),
        svg.to_str().expect("utf-8"),
        "--vars",
        "NOPE",
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("no variable \"NOPE\" in the trace"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn a_joint_machine_trace_plots_its_joints_and_tool_pose_by_default_and_exports_to_vcd() {
    let dir = tempfile::tempdir().expect("tempdir");
    let trace = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/traces/hexapod-jog-bridge-fault.jsonl.gz");
    let svg = dir.path().join("h.svg");
    let o = pkm(&[
        "trace",
        "plot",
        trace.to_str().expect("utf-8"),
        svg.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let text = std::fs::read_to_string(&svg).expect("svg");
    for caption in ["JOINT1_POSITION", "JOINT6_POSITION", "TOOL_X", "TOOL_C"] {
        assert!(text.contains(&format!("\n{caption}\n</text>")), "panel {caption}");
    }
    let vcd = dir.path().join("h.vcd");
    let o = pkm(&[
        "trace",
        "vcd",
        trace.to_str().expect("utf-8"),
        vcd.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let text = std::fs::read_to_string(&vcd).expect("vcd");
    assert!(text.contains(" TOOL_Z $end"), "the tool pose in the VCD");
    assert!(
        text.contains("motor_bridge_error_joint_3"),
        "the error reason as a string"
    );
}

#[test]
fn a_trace_write_error_is_reported_with_exit_code_1_after_the_summary() {
    let dir = tempfile::tempdir().expect("tempdir");
    let summary = dir.path().join("summary.json");
    let o = pkm(&[
        "run",
        "--virtual",
        "--duration",
        "2",
        "--trace",
        "/dev/full",
        "--summary",
        summary.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).ends_with(
            "error: /dev/full: writing the trace failed: No space left on device (os error 28); recording stopped \
             there, the run went on: the file holds no complete record\n"
        ),
        "{}",
        stderr(&o)
    );
    // The run went on to its end, and its summary was written.
    let s = common::read_json(&summary);
    assert_eq!(s["task_classes"][0]["cycles"], 200, "{s}");
}

/// A trace whose file stops growing mid-run (here a file size limit, as a full disk
/// would) reports the records actually in the file — read back as `replay` reads them, not
/// guessed from the last flush — and `replay` finds that many, identical.
#[test]
fn a_trace_write_error_reports_the_records_the_file_holds() {
    use std::os::unix::process::CommandExt;
    let dir = tempfile::tempdir().expect("tempdir");
    let trace = dir.path().join("cut.jsonl");
    let mut run = crate::common::pkm_command();
    run.args([
        "run",
        "--virtual",
        "--duration",
        "30",
        "--trace",
        trace.to_str().expect("utf-8"),
    ])
    .current_dir(env!("CARGO_MANIFEST_DIR"))
    .env("RUST_LOG", "warn");
    // SAFETY: between fork and exec the child only sets its file size limit (200 kB) and
    // ignores SIGXFSZ, so that a write beyond the limit fails with EFBIG: async-signal-safe calls.
    unsafe {
        run.pre_exec(|| {
            let limit = libc::rlimit {
                rlim_cur: 200_000,
                rlim_max: 200_000,
            };
            if libc::setrlimit(libc::RLIMIT_FSIZE, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            Ok(())
        });
    }
    let o = run.output().expect("runs");
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let log = stderr(&o);
    let held = log
        .split("the file holds the first ")
        .nth(1)
        .unwrap_or_else(|| panic!("no count of the records held: {log}"));
    let records: u64 = held.split(' ').next().and_then(|n| n.parse().ok()).expect("a count");
    assert!(log.contains("File too large (os error 27)"), "{log}");
    assert!(records > 100, "{records} records");
    let o = pkm(&["replay", trace.to_str().expect("utf-8")]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(
        stdout(&o).contains(&format!("identical up to the cut: {records} records")),
        "{} vs {records}",
        stdout(&o)
    );
}

#[test]
fn a_trace_knows_its_machine_replay_takes_it_and_a_wrong_one_is_named() {
    let root = common::root();
    let trace = root.join("tests/traces/hexapod-jog-bridge-fault.jsonl.gz");
    let trace = trace.to_str().expect("utf-8");
    // Without --machine: the trace's digest is the hexapod's own configuration's.
    let o = common::pkm(&["replay", trace]);
    assert_eq!(o.status.code(), Some(0), "{}", common::stderr(&o));
    assert!(common::stdout(&o).contains(": identical: "), "{}", common::stdout(&o));
    // Another machine's configuration: refused, and the right one suggested.
    let o = common::pkm(&["replay", trace, "--machine", "ox-x"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        common::stderr(&o).contains("it was recorded with machine hexapod's own configuration: replay it with --machine hexapod, or use --force to replay anyway"),
        "{}",
        common::stderr(&o)
    );
    // A new trace names its machine in the header.
    let dir = tempfile::tempdir().expect("tempdir");
    let recorded = common::record_machine_trace(dir.path(), "pn101.jsonl", 1, "[]", &["--machine", "pn101"]);
    let header = std::fs::read_to_string(&recorded).expect("the trace");
    let header: serde_json::Value = serde_json::from_str(header.lines().next().expect("a header")).expect("JSON");
    assert_eq!(header["machine"], "pn101");
}
