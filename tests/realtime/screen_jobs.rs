//! The screen's jobs against a running PLC: a job whose text nests without end is
//! refused with its line and column while the PLC runs on (such a job aborted the process
//! before); a job being planned is abandoned by the operator's Cancel and by STOP; and SIGTERM
//! ends the run at once, summary written, while a job is still being planned (the run waited
//! for the plan before, minutes for a large one).

use std::time::{Duration, Instant};

use crate::common;
use crate::screen_ws::{Ws, next_within, reply, send, start_with_screen, until_state};

/// A job that reads for a minute or more: a loop of twenty million lines without a move (the
/// PLC's bound on lines read). Its planning is under way while the test acts on it.
const LONG: &str = "#1=0\no1 while [#1 LT 100000000]\n#1=[#1+1]\no1 endwhile";

/// Sends MDI `text`; the screen says it plans it.
async fn mdi(ws: &mut Ws, text: &str) {
    send(ws, serde_json::json!({"cmd": "mdi", "text": text})).await;
    // A busy machine may take seconds to start the job's planning.
    let m = reply(ws, Duration::from_secs(30)).await;
    assert_eq!(m["type"], "planning", "{m}");
}

/// The refusal of the job being planned.
async fn job_refused(ws: &mut Ws) -> String {
    let m = reply(ws, Duration::from_secs(30)).await;
    assert_eq!((&m["type"], &m["job"]), (&"refused".into(), &true.into()), "{m}");
    m["why"].as_str().expect("why").to_string()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn jobs_that_nest_or_plan_for_long_never_take_the_plc_down_or_hold_it_up() {
    let dir = tempfile::tempdir().expect("tempdir");
    // No time bound that a job could reach here: what ends its planning is the operator.
    let config = common::ox_config(dir.path(), true, |c| c["nc"]["max_planning_s"] = 600.into());
    let summary = dir.path().join("summary.json");
    let mut command = common::pkm_command();
    command
        .args(["run", "--config", config.to_str().expect("utf-8")])
        .args(["--hmi", "127.0.0.1:0", "--joystick", "none"])
        .args(["--summary", summary.to_str().expect("utf-8")])
        .env("RUST_LOG", "info");
    let (mut plc, mut ws) = start_with_screen(command).await;
    until_state(&mut ws, "READY", Duration::from_secs(60)).await;
    // Outside ERROR an acknowledgement would be a STOP: refused.
    send(&mut ws, serde_json::json!({"cmd": "acknowledge"})).await;
    let m = reply(&mut ws, Duration::from_secs(10)).await;
    assert_eq!(
        (&m["type"], &m["why"]),
        (
            &"refused".into(),
            &"there is no error to acknowledge: the machine is not in ERROR".into()
        ),
        "{m}"
    );

    // A thousand brackets deep: refused where it passes the bound; the PLC runs on.
    mdi(&mut ws, &format!("G1 X{}1{} F100", "[".repeat(1000), "]".repeat(1000))).await;
    assert_eq!(
        job_refused(&mut ws).await,
        "MDI:1:69: the value nests deeper than 64 levels (brackets, signs, parameters of parameters and functions, counted together): write it in steps with parameters"
    );
    until_state(&mut ws, "READY", Duration::from_secs(30)).await;

    // Cancelled while it is planned.
    mdi(&mut ws, LONG).await;
    let asked = Instant::now();
    send(&mut ws, serde_json::json!({"cmd": "cancel"})).await;
    let why = job_refused(&mut ws).await;
    eprintln!("screen_jobs: the cancel took {:.3} s", asked.elapsed().as_secs_f64());
    assert!(
        why.starts_with("MDI:") && why.ends_with(": abandoned while it was being planned: cancelled by the operator"),
        "{why}"
    );

    // Abandoned by STOP; the error acknowledged, READY again.
    mdi(&mut ws, LONG).await;
    send(&mut ws, serde_json::json!({"cmd": "stop"})).await;
    let why = job_refused(&mut ws).await;
    assert!(
        why.ends_with(": abandoned while it was being planned: STOP pressed"),
        "{why}"
    );
    until_state(&mut ws, "ERROR", Duration::from_secs(30)).await;
    // The acknowledgement, sent at once: it presses STOP once the lockout after the first has
    // passed (a STOP sent now would be ignored, and a second one, sent after the lockout, might
    // find the machine acknowledged and stop it again).
    send(&mut ws, serde_json::json!({"cmd": "acknowledge"})).await;
    until_state(&mut ws, "READY", Duration::from_secs(60)).await;

    // SIGTERM while a job is planned: the run ends at once, its outputs safe, its summary written.
    mdi(&mut ws, LONG).await;
    let signalled = Instant::now();
    // SAFETY: kill sends a signal to the child this test started; no memory is involved.
    assert_eq!(unsafe { libc::kill(plc.child.id() as i32, libc::SIGTERM) }, 0);
    let status = plc.wait();
    let took = signalled.elapsed();
    eprintln!(
        "screen_jobs: SIGTERM during planning: the run ended {:.3} s after the signal",
        took.as_secs_f64()
    );
    assert!(status.success(), "{status}: {}", plc.log());
    // The plan would have gone on for a minute or more: the run did not wait for it.
    assert!(
        took < Duration::from_secs(15),
        "ended {took:?} after SIGTERM: {}",
        plc.log()
    );
    let written = common::read_json(&summary);
    assert_eq!(written["main"]["state"], "READY", "{written}");
    assert!(!plc.log().contains("panicked"), "{}", plc.log());
}

/// Waits for a frame whose note contains `note`.
async fn until_note(ws: &mut Ws, note: &str, within: Duration) {
    let start = Instant::now();
    loop {
        let m = next_within(ws, within.saturating_sub(start.elapsed()))
            .await
            .unwrap_or_else(|| panic!("no frame noting {note:?} within {within:?}"));
        if m["type"] == "frame" && m["note"].as_str().is_some_and(|n| n.contains(note)) {
            return;
        }
    }
}

/// The screen's refusal of the tool change confirmation `{tool, change}`, or `None` when it was
/// taken (no reply within a second).
async fn confirm_tool(ws: &mut Ws, tool: i32, change: i32) -> Option<String> {
    send(
        ws,
        serde_json::json!({"cmd": "tool_changed", "tool": tool, "change": change}),
    )
    .await;
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(1) {
        let m = next_within(ws, Duration::from_secs(1).saturating_sub(start.elapsed())).await?;
        if m["type"] == "refused" {
            return Some(m["why"].as_str().expect("why").to_string());
        }
    }
    None
}

/// A confirmation names the tool and the change it answers: one for another change — the
/// first change's, arriving again while the second waits (a late second click, which confirmed
/// the next change before) — is refused, logged, and confirms nothing.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tool_change_confirmation_answers_its_own_change_only() {
    let dir = tempfile::tempdir().expect("tempdir");
    let config = common::ox_config(dir.path(), true, |_| {});
    let table = dir.path().join("tool.tbl");
    std::fs::write(&table, "T1 P1 Z10 ;6 mm end mill\nT2 P2 Z20 ;3 mm drill\n").expect("the table");
    let program = dir.path().join("tools.ngc");
    std::fs::write(&program, "T1 M6\nG1 X1 F600\nT2 M6\nG0 X0\nM2\n").expect("the program");
    let mut command = common::pkm_command();
    command
        .args(["run", "--config", config.to_str().expect("utf-8")])
        .args(["--hmi", "127.0.0.1:0", "--joystick", "none"])
        .args(["--program", program.to_str().expect("utf-8")])
        .args(["--tool-table", table.to_str().expect("utf-8")])
        .env("RUST_LOG", "info");
    let (mut plc, mut ws) = start_with_screen(command).await;
    // Before any change waits, a confirmation is refused as such.
    assert_eq!(
        confirm_tool(&mut ws, 1, 1).await.as_deref(),
        Some("the confirmation of tool 1 (change 1) is refused: no tool change waits")
    );
    let change = "tool change (M6)";
    until_note(&mut ws, change, Duration::from_secs(120)).await;
    assert_eq!(
        confirm_tool(&mut ws, 2, 1).await.as_deref(),
        Some("the confirmation of tool 2 (change 1) is refused: change 1 waits, for tool 1")
    );
    assert_eq!(confirm_tool(&mut ws, 1, 1).await, None, "the right one is taken");
    // The first change's confirmation again — taken while the first change still showed, then
    // refused as none waits — until the second change waits: refused, and a second later the
    // second change still waits.
    let second = "the confirmation of tool 1 (change 1) is refused: change 2 waits, for tool 2";
    let start = Instant::now();
    loop {
        let why = confirm_tool(&mut ws, 1, 1).await;
        if why.as_deref() == Some(second) {
            break;
        }
        assert!(
            why.as_deref().is_none_or(|w| w.ends_with("no tool change waits")),
            "{why:?}"
        );
        assert!(start.elapsed() < Duration::from_secs(30), "no second change");
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
    tokio::time::sleep(Duration::from_secs(1)).await;
    assert_eq!(
        confirm_tool(&mut ws, 1, 1).await.as_deref(),
        Some("the confirmation of tool 1 (change 1) is refused: change 2 waits, for tool 2")
    );
    assert_eq!(confirm_tool(&mut ws, 2, 2).await, None);
    until_state(&mut ws, "READY", Duration::from_secs(60)).await;
    plc.terminate();
    let log = plc.log();
    assert!(log.contains("tool change 1 confirmed: tool 1 in the spindle"), "{log}");
    assert!(log.contains("tool change 2 confirmed: tool 2 in the spindle"), "{log}");
    assert!(
        log.contains("the confirmation of tool 1 (change 1) is refused: change 2 waits, for tool 2"),
        "logged: {log}"
    );
}
