//! The simulation mode: `run --virtual --pace X` serves the operator's screen as a real-time run
//! does, while the cycles run in virtual time paced at X times real time — a student loads a
//! program on the screen, starts it and watches it run on the simulated machine; the run is
//! traced and replays identically, as every virtual run does.

use std::time::{Duration, Instant};

use crate::common;
use crate::screen_ws::{send, start_with_screen, until_state};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_paced_simulation_serves_the_screen_runs_a_program_and_replays() {
    let dir = tempfile::tempdir().expect("a temporary directory");
    let programs = dir.path().join("programs");
    std::fs::create_dir(&programs).expect("the directory");
    std::fs::copy(
        common::root().join("programs/ox-x-target.ngc"),
        programs.join("ox-x-target.ngc"),
    )
    .expect("copied");
    let (trace, summary) = (dir.path().join("sim.jsonl"), dir.path().join("summary.json"));
    let mut command = common::pkm_command();
    command.args([
        "run",
        "--machine",
        "ox-x",
        "--virtual",
        "--pace",
        "20",
        "--hmi",
        "127.0.0.1:0",
    ]);
    command.args(["--opcua", "none", "--programs"]).arg(&programs);
    command.arg("--trace").arg(&trace).arg("--summary").arg(&summary);
    let started = Instant::now();
    let (mut plc, mut ws) = start_with_screen(command).await;
    // The screen is told it shows a simulation (it says so in its header).
    let hello = plc.log();
    assert!(
        hello.contains("simulation: virtual time paced at 20x real time"),
        "{hello}"
    );
    let ready = until_state(&mut ws, "READY", Duration::from_secs(120)).await;
    // Paced: simulated time never runs ahead of 20 times the wall clock (it may fall behind on
    // a busy machine; the run's figures are in its log).
    let (t_ready, wall) = (ready["t_s"].as_f64().expect("t_s"), started.elapsed().as_secs_f64());
    assert!(
        t_ready <= 20.0 * wall + 0.5,
        "READY at t={t_ready} s after {wall} s of wall clock"
    );
    // The program the student loads and starts runs to its end on the simulated machine.
    send(&mut ws, serde_json::json!({"cmd": "load", "program": 1})).await;
    send(&mut ws, serde_json::json!({"cmd": "program", "what": "start"})).await;
    let auto = until_state(&mut ws, "AUTO", Duration::from_secs(60)).await;
    let done = until_state(&mut ws, "READY", Duration::from_secs(120)).await;
    let ran_s = done["t_s"].as_f64().expect("t_s") - auto["t_s"].as_f64().expect("t_s");
    assert!(ran_s > 5.0, "the program ran {ran_s} s of simulated time");
    let status = plc.terminate();
    assert!(status.success(), "{status:?}\n{}", plc.log());
    let log = plc.log();
    assert!(log.contains("simulation paced at 20x real time: "), "{log}");
    let written = common::read_json(&summary);
    assert_eq!(written["mode"], "paced", "{written}");
    // Deterministic: the trace replays identically, the screen's commands with it.
    common::assert_replays_identically(&trace, &["--machine", "ox-x"]);
}

/// A program's `G10 L1` is written back to the tool table as a machine's run reaches it, as
/// LinuxCNC writes it: the entry whole, in LinuxCNC's format, the file's other tools kept. A
/// simulation of the same program (`--virtual`) keeps the change for its run and leaves the file
/// as it was: it checks programs for the machine, it must not change the machine's tools.
#[test]
fn a_programs_g10_l1_is_written_back_by_the_machine_and_kept_by_a_simulation() {
    let dir = tempfile::tempdir().expect("a temporary directory");
    let table = dir.path().join("tool.tbl");
    let original = "T1 P1 Z0 D6 ;6 mm end mill\nT2 P2 Z0 D3 ;3 mm drill\n";
    std::fs::write(&table, original).expect("the table");
    let program = dir.path().join("g10.ngc");
    std::fs::write(&program, "G21 G90\nG10 L1 P1 Z2 R1.5\nG0 X1\nG0 X0\nM2\n").expect("the program");
    let config = common::ox_config(dir.path(), true, |_| {});
    let arg = |p: &std::path::Path| p.to_str().expect("utf-8").to_string();
    // The simulation first: the file as it was.
    let o = common::pkm_command()
        .args(["run", "--config", &arg(&config), "--virtual", "--duration", "20"])
        .args(["--program", &arg(&program), "--tool-table", &arg(&table)])
        .env("RUST_LOG", "info")
        .output()
        .expect("pkm-plc runs");
    assert_eq!(o.status.code(), Some(0), "{}", common::stderr(&o));
    assert!(
        common::stderr(&o)
            .contains("NC line 2: tool 1's entry kept for this simulation (a simulation does not write the tool table"),
        "{}",
        common::stderr(&o)
    );
    assert_eq!(std::fs::read_to_string(&table).expect("the table"), original);
    // The machine: written when the run reaches line 2.
    let mut command = common::pkm_command();
    command.args([
        "run",
        "--config",
        &arg(&config),
        "--hmi",
        "none",
        "--opcua",
        "none",
        "--joystick",
        "none",
    ]);
    command.args([
        "--duration",
        "120",
        "--program",
        &arg(&program),
        "--tool-table",
        &arg(&table),
    ]);
    command.env("RUST_LOG", "info");
    let (mut run, _) = common::Logged::start(command, "configuration: ", Duration::from_secs(30));
    let written = run.wait_for(0, "NC line 2: tool 1's entry written to ", Duration::from_secs(90));
    assert!(written.is_some(), "{}", run.log());
    assert_eq!(
        std::fs::read_to_string(&table).expect("the table"),
        "T1 P1 Z+2.000000 D3.000000 ;6 mm end mill\nT2 P2 D3.000000 ;3 mm drill\n"
    );
    let status = run.terminate();
    assert!(status.success(), "{status:?}\n{}", run.log());
}
