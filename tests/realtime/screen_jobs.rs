//! The screen's jobs against a running PLC: a job whose text nests without end is
//! refused with its line and column while the PLC runs on (such a job aborted the process
//! before); a job being planned is abandoned by the operator's Cancel and by STOP; and SIGTERM
//! ends the run at once, summary written, while a job is still being planned (the run waited
//! for the plan before, minutes for a large one).

use std::time::{Duration, Instant};

use futures::{SinkExt, StreamExt};
use tokio_tungstenite::tungstenite::Message;

use crate::common;

/// A WebSocket client of the screen.
type Ws = tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// A job that reads for a minute or more: a loop of twenty million lines without a move (the
/// PLC's bound on lines read). Its planning is under way while the test acts on it.
const LONG: &str = "#1=0\no1 while [#1 LT 100000000]\n#1=[#1+1]\no1 endwhile";

/// The screen's next message as JSON; panics after `within`.
async fn next(ws: &mut Ws, within: Duration) -> serde_json::Value {
    next_within(ws, within)
        .await
        .unwrap_or_else(|| panic!("no message from the screen within {within:?}"))
}

/// The screen's next message as JSON, `None` when none comes within `within`.
async fn next_within(ws: &mut Ws, within: Duration) -> Option<serde_json::Value> {
    tokio::time::timeout(within, async {
        loop {
            match ws.next().await {
                Some(Ok(Message::Text(t))) => return serde_json::from_str(&t).expect("JSON"),
                Some(Ok(_)) => {}
                other => panic!("the connection ended: {other:?}"),
            }
        }
    })
    .await
    .ok()
}

/// The next message that is a reply to a command: not a frame, nor what the screen tells every
/// page (an alarm of the history, the work offsets after a touch-off).
async fn reply(ws: &mut Ws, within: Duration) -> serde_json::Value {
    let start = Instant::now();
    loop {
        let m = next(ws, within.saturating_sub(start.elapsed())).await;
        if !matches!(m["type"].as_str(), Some("frame" | "alarm" | "origins")) {
            return m;
        }
    }
}

/// Waits for a frame in `state`.
async fn until_state(ws: &mut Ws, state: &str, within: Duration) {
    let start = Instant::now();
    let mut last = serde_json::Value::Null;
    loop {
        let left = within.saturating_sub(start.elapsed());
        let m = next_within(ws, left).await.unwrap_or_else(|| {
            panic!(
                "not {state} within {within:?}; the last frame's state {}, reason {}, note {}",
                last["state"], last["reason"], last["note"]
            )
        });
        if m["type"] == "frame" {
            if m["state"] == state {
                return;
            }
            last = m;
        }
    }
}

async fn send(ws: &mut Ws, command: serde_json::Value) {
    ws.send(Message::Text(command.to_string().into()))
        .await
        .expect("the command is sent");
}

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
    let (mut plc, url) = common::Logged::start(command, "operator screen at ", Duration::from_secs(30));
    let ws_url = url.replacen("http://", "ws://", 1) + "ws";
    let (mut ws, _) = tokio_tungstenite::connect_async(ws_url.as_str())
        .await
        .expect("connects");
    assert_eq!(next(&mut ws, Duration::from_secs(10)).await["type"], "hello");
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
