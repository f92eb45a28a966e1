//! The operator's screen end to end, in real time: the soft-PLC serves it (`run --hmi`), a
//! headless Chromium (Debian's `chromium`; `.ci/run` installs it where missing) loads the page,
//! sees INIT then READY, holds a jog button and sees the tool move, releases it and sees it stop,
//! presses STOP and sees ERROR with its reason, acknowledges and sees INIT. A second test drops a
//! WebSocket mid-jog and sees the jog stop within a main cycle.
//!
//! Without a Chromium the browser test says so on stderr and is skipped (it passes): the machine
//! it runs on cannot have one.

#[path = "common/mod.rs"]
mod common;

use std::io::BufRead;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use chromiumoxide::cdp::browser_protocol::input::{DispatchMouseEventParams, DispatchMouseEventType, MouseButton};
use chromiumoxide::{Browser, BrowserConfig, Page};
use futures::StreamExt;

/// The tests run one at a time: each runs a PLC in real time (and one a browser), and on a small
/// machine side by side they would starve each other.
static SERIAL: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// A running `pkm-plc run` with its screen, killed when dropped.
struct Plc {
    child: Child,
    url: String,
}

impl Drop for Plc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The O-X glide's configuration for these tests, written to `dir`: they test the screen, not
/// the scheduler's timing, so a late cycle on a busy machine is logged rather than an ERROR (as
/// the other real-time end-to-end tests do; timing has its own benchmarks).
fn test_config(dir: &std::path::Path) -> std::path::PathBuf {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut config = common::read_json(&root.join("machines/ox-x.json"));
    config["io_map"] = root.join("io-map/ox-x.json").to_str().expect("utf-8").into();
    for class in config["task_classes"].as_array_mut().expect("classes") {
        class["on_violation"] = "log".into();
    }
    let path = dir.join("ox-x.json");
    std::fs::write(&path, config.to_string()).expect("write the configuration");
    path
}

/// Starts `pkm-plc run` in real time on the configuration `config` with the screen on a free
/// loopback port (and `more` arguments); returns when the screen's address is logged.
fn start_plc(config: &std::path::Path, seconds: u32, more: &[&str]) -> Plc {
    let mut child = Command::new(env!("CARGO_BIN_EXE_pkm-plc"))
        .args([
            "run",
            "--config",
            config.to_str().expect("utf-8"),
            "--hmi",
            "127.0.0.1:0",
            "--joystick",
            "none",
            "--duration",
            &seconds.to_string(),
        ])
        .args(more)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("pkm-plc starts");
    let stderr = child.stderr.take().expect("stderr");
    let (tx, rx) = std::sync::mpsc::channel();
    // Drains the log for the whole run (a full pipe would block the PLC's logging).
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stderr).lines().map_while(Result::ok) {
            if let Some(at) = line.split("operator screen at ").nth(1) {
                let _ = tx.send(at.split_whitespace().next().unwrap_or("").to_string());
            }
        }
    });
    let url = rx
        .recv_timeout(Duration::from_secs(30))
        .expect("the screen's address is logged");
    Plc { child, url }
}

/// Debian's `chromium`, or another Chromium or Chrome on the PATH.
fn chromium() -> Option<std::path::PathBuf> {
    ["chromium", "chromium-browser", "google-chrome", "google-chrome-stable"]
        .iter()
        .find_map(|name| {
            let out = Command::new("which").arg(name).output().ok()?;
            let path = String::from_utf8(out.stdout).ok()?.trim().to_string();
            (out.status.success() && !path.is_empty()).then(|| path.into())
        })
}

/// A text of the page: the value of a JavaScript expression.
async fn text(page: &Page, expression: &str) -> String {
    page.evaluate(expression)
        .await
        .ok()
        .and_then(|r| r.into_value::<String>().ok())
        .unwrap_or_default()
}

/// The state shown.
async fn state(page: &Page) -> String {
    text(page, "document.getElementById('state').textContent").await
}

/// The tool's x shown.
async fn x(page: &Page) -> f64 {
    shown(page, "x").await
}

/// A position shown (`x`, `q1`, …).
async fn shown(page: &Page, name: &str) -> f64 {
    text(
        page,
        &format!("(document.querySelector('[data-value={name}]') || {{}}).textContent || ''"),
    )
    .await
    .parse()
    .unwrap_or(f64::NAN)
}

/// Waits until `check` holds for the page, at most `within`.
async fn until(page: &Page, within: Duration, what: &str, check: impl AsyncFn(&Page) -> bool) {
    let start = Instant::now();
    while !check(page).await {
        if start.elapsed() >= within {
            let shown = state(page).await;
            let link = text(page, "document.getElementById('link').textContent").await;
            panic!("{what}: not within {within:?} (the page shows {shown:?}, link {link:?})");
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// The centre of the element `selector`, scrolled into view.
async fn centre(page: &Page, selector: &str) -> (f64, f64) {
    let r: Vec<f64> = page
        .evaluate(format!(
            "(() => {{ const e = document.querySelector({selector:?}); e.scrollIntoView({{block: 'center'}}); const r = e.getBoundingClientRect(); return [r.x + r.width / 2, r.y + r.height / 2]; }})()"
        ))
        .await
        .expect("evaluates")
        .into_value()
        .expect("two numbers");
    (r[0], r[1])
}

/// Presses (or releases) the mouse's left button at `at`, as a hand on the page would.
async fn mouse(page: &Page, at: (f64, f64), pressed: bool) {
    let kind = if pressed {
        DispatchMouseEventType::MousePressed
    } else {
        DispatchMouseEventType::MouseReleased
    };
    let event = DispatchMouseEventParams::builder()
        .r#type(kind)
        .x(at.0)
        .y(at.1)
        .button(MouseButton::Left)
        .click_count(1)
        .build()
        .expect("a mouse event");
    page.execute(event).await.expect("the mouse event is dispatched");
}

/// A WebSocket client of the screen.
type Ws = tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// The screen's next message (the hello, a frame, a refusal) as JSON.
async fn next(ws: &mut Ws) -> serde_json::Value {
    use tokio_tungstenite::tungstenite::Message;
    loop {
        match ws.next().await {
            Some(Ok(Message::Text(t))) => return serde_json::from_str(&t).expect("JSON"),
            Some(Ok(_)) => {}
            other => panic!("the connection ended: {other:?}"),
        }
    }
}

async fn click(page: &Page, selector: &str) {
    let at = centre(page, selector).await;
    mouse(page, at, true).await;
    mouse(page, at, false).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_shows_referencing_jogs_while_held_stops_and_acknowledges() {
    let Some(chromium) = chromium() else {
        eprintln!(
            "SKIPPED hmi_browser::the_page_shows_referencing_jogs_while_held_stops_and_acknowledges: \
             no Chromium here (apt-get install chromium)"
        );
        return;
    };
    let _serial = SERIAL.lock().await;
    let profile = tempfile::tempdir().expect("tempdir");
    let trace = profile.path().join("screen.jsonl");
    // The browser first: a cold start on a busy machine takes seconds, and the page must load
    // while the machine still references.
    let config = BrowserConfig::builder()
        .chrome_executable(chromium)
        .no_sandbox()
        .user_data_dir(profile.path().join("profile"))
        .arg("--disable-gpu")
        .window_size(1280, 1400)
        .build()
        .expect("a browser configuration");
    let (mut browser, mut handler) = Browser::launch(config).await.expect("Chromium starts");
    let events = tokio::spawn(async move { while handler.next().await.is_some() {} });
    let blank = browser.new_page("about:blank").await.expect("a page");
    let config = test_config(profile.path());
    let mut plc = start_plc(&config, 90, &["--trace", trace.to_str().expect("utf-8")]);
    blank.goto(plc.url.as_str()).await.expect("the page loads");
    let page = blank;
    // INIT while the machine references, then READY (O-X: 11.65 s of referencing).
    until(&page, Duration::from_secs(30), "INIT shown", async |p| {
        state(p).await == "INIT"
    })
    .await;
    until(&page, Duration::from_secs(60), "READY shown", async |p| {
        state(p).await == "READY"
    })
    .await;
    // The programs of programs/ that fit the O-X glide are offered, the first loaded: load the
    // second (the text) in its place.
    let file = async |p: &Page| text(p, "document.getElementById('program-file').textContent").await;
    assert!(file(&page).await.ends_with("ox-x-target.ngc"), "{}", file(&page).await);
    page.evaluate("document.getElementById('program-choice').value = '2'")
        .await
        .expect("a program chosen");
    click(&page, "#nc-load").await;
    until(&page, Duration::from_secs(5), "the text loaded", async |p| {
        file(p).await.ends_with("ox-x-text.ngc")
    })
    .await;
    assert!(
        text(&page, "document.getElementById('program-text').textContent")
            .await
            .contains("O-X GLIDE"),
        "its text shown"
    );
    // Hold +x: the tool moves while held.
    let before = x(&page).await;
    // The +x button (the first pose coordinate).
    let button = centre(&page, r#".jog-btn[data-axis="1"][data-x="1"]"#).await;
    mouse(&page, button, true).await;
    until(&page, Duration::from_secs(10), "the tool moves", async |p| {
        x(p).await > before + 2.0
    })
    .await;
    assert_eq!(state(&page).await, "MOTION");
    mouse(&page, button, false).await;
    // Released: it stops (READY, and x stays).
    until(&page, Duration::from_secs(5), "READY after the release", async |p| {
        state(p).await == "READY"
    })
    .await;
    // The steppers settle onto the set-point (their regulator takes back a few hundredths of a
    // millimetre of overshoot), then the tool stands.
    until(&page, Duration::from_secs(3), "the tool stands", async |p| {
        let a = x(p).await;
        tokio::time::sleep(Duration::from_millis(300)).await;
        (x(p).await - a).abs() < 0.003
    })
    .await;
    let stood = x(&page).await;
    tokio::time::sleep(Duration::from_millis(500)).await;
    assert!((x(&page).await - stood).abs() < 0.003, "the tool stands at {stood}");
    // Hold +q3 (the O-X glide's serial axis): that joint alone moves.
    let joints = async |p: &Page| [shown(p, "q1").await, shown(p, "q2").await, shown(p, "q3").await];
    let before = joints(&page).await;
    let button = centre(&page, r#".jog-btn[data-axis="-3"][data-x="1"]"#).await;
    mouse(&page, button, true).await;
    until(&page, Duration::from_secs(10), "joint 3 moves", async |p| {
        shown(p, "q3").await > before[2] + 2.0
    })
    .await;
    mouse(&page, button, false).await;
    until(
        &page,
        Duration::from_secs(5),
        "READY after the joint's release",
        async |p| state(p).await == "READY",
    )
    .await;
    let after = joints(&page).await;
    for j in 0..2 {
        assert!(
            (after[j] - before[j]).abs() < 0.01,
            "joint {} stayed: {before:?} → {after:?}",
            j + 1
        );
    }
    // STOP: ERROR with its reason; acknowledge after the lockout: INIT.
    click(&page, "#stop").await;
    until(&page, Duration::from_secs(5), "ERROR shown", async |p| {
        state(p).await == "ERROR"
    })
    .await;
    assert_eq!(
        text(&page, "document.getElementById('reason').textContent").await,
        "STOP"
    );
    tokio::time::sleep(Duration::from_millis(1200)).await;
    click(&page, "#ack").await;
    until(
        &page,
        Duration::from_secs(5),
        "INIT after the acknowledgement",
        async |p| matches!(state(p).await.as_str(), "REBOOT" | "INIT"),
    )
    .await;
    let _ = browser.close().await;
    let _ = browser.wait().await;
    events.abort();
    // The screen's commands are inputs like the panel's: in the trace, and replayed.
    let stopped = Command::new("kill")
        .args(["-TERM", &plc.child.id().to_string()])
        .status()
        .expect("kill runs");
    assert!(stopped.success());
    assert!(plc.child.wait().expect("the run ends").success());
    let recorded = std::fs::read_to_string(&trace).expect("the trace");
    assert!(
        recorded.contains(r#""HMI_STOP":true"#),
        "the screen's STOP is in the trace"
    );
    assert!(
        recorded.contains(r#""HMI_JOG_X":1.0"#),
        "the screen's jog is in the trace"
    );
    assert!(
        recorded.contains(r#""HMI_NC_PROGRAM":2"#),
        "the screen's load is in the trace"
    );
    common::assert_replays_identically(&trace, &["--config", config.to_str().expect("utf-8")]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_websocket_dropped_mid_jog_stops_the_jog_within_a_main_cycle() {
    use futures::SinkExt;
    use tokio_tungstenite::tungstenite::Message;
    let _serial = SERIAL.lock().await;
    let dir = tempfile::tempdir().expect("tempdir");
    let plc = start_plc(&test_config(dir.path()), 60, &[]);
    let ws = plc.url.replacen("http://", "ws://", 1) + "ws";
    // A watcher, and a client that jogs.
    let (mut watcher, _) = tokio_tungstenite::connect_async(ws.as_str()).await.expect("connects");
    let (mut jogger, _) = tokio_tungstenite::connect_async(ws.as_str()).await.expect("connects");
    // The hello (the variables' names) comes first, then a frame per main cycle.
    let hello = next(&mut watcher).await;
    assert_eq!(hello["type"], "hello");
    let jog = hello["variables"]
        .as_array()
        .expect("variables")
        .iter()
        .position(|p| p[0] == "HMI_JOG_X")
        .expect("HMI_JOG_X in the image");
    // Every frame as it arrives: (when, seq, the jog, the state).
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    tokio::spawn(async move {
        loop {
            // Ends with the connection (the PLC ends with the test).
            let f = match watcher.next().await {
                Some(Ok(Message::Text(t))) => serde_json::from_str::<serde_json::Value>(&t).expect("JSON"),
                Some(Ok(_)) => continue,
                _ => break,
            };
            let entry = (
                Instant::now(),
                f["seq"].as_u64().unwrap_or(0),
                f["image"][jog].as_f64().unwrap_or(f64::NAN),
                f["state"].as_str().unwrap_or("").to_string(),
            );
            if tx.send(entry).is_err() {
                break;
            }
        }
    });
    // READY first.
    let start = Instant::now();
    loop {
        let (_, _, _, state) = rx.recv().await.expect("frames");
        if state == "READY" {
            break;
        }
        assert!(start.elapsed() < Duration::from_secs(60), "READY in time");
    }
    // Jog, refreshed every 20 ms for a second.
    for _ in 0..50 {
        jogger
            .send(Message::Text(r#"{"cmd":"jog","x":1,"y":0}"#.into()))
            .await
            .expect("sends");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    // The connection drops (no close frame).
    drop(jogger);
    let dropped = Instant::now();
    tokio::time::sleep(Duration::from_millis(500)).await;
    let mut frames = Vec::new();
    while let Ok(f) = rx.try_recv() {
        frames.push(f);
    }
    let before: Vec<&(Instant, u64, f64, String)> = frames.iter().filter(|f| f.0 < dropped).collect();
    assert!(
        before.iter().rev().take(5).all(|f| f.2 == 1.0 && f.3 == "MOTION"),
        "jogging before the drop: {:?}",
        before.iter().rev().take(5).map(|f| (f.2, &f.3)).collect::<Vec<_>>()
    );
    let after: Vec<&(Instant, u64, f64, String)> = frames.iter().filter(|f| f.0 >= dropped).collect();
    let stopped = after
        .iter()
        .position(|f| f.2 == 0.0)
        .expect("the jog stopped after the drop");
    assert!(after[stopped..].iter().all(|f| f.2 == 0.0), "and stayed stopped");
    let delay = after[stopped].0 - dropped;
    eprintln!("the jog read 0 in a frame {} ms after the drop", delay.as_millis());
    // One main cycle (50 ms), and the frame's way to this client.
    assert!(delay < Duration::from_millis(100), "{} ms", delay.as_millis());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn with_a_token_a_page_without_it_only_watches() {
    use futures::SinkExt;
    use tokio_tungstenite::tungstenite::Message;
    async fn state_after(ws: &mut Ws, frames: usize) -> String {
        let mut state = String::new();
        for _ in 0..frames {
            let f = next(ws).await;
            if f["type"] == "frame" {
                state = f["state"].as_str().unwrap_or("").to_string();
            }
        }
        state
    }
    let _serial = SERIAL.lock().await;
    let dir = tempfile::tempdir().expect("tempdir");
    let plc = start_plc(&test_config(dir.path()), 30, &["--hmi-token", "s3cret"]);
    let ws = plc.url.replacen("http://", "ws://", 1) + "ws";
    let (mut watcher, _) = tokio_tungstenite::connect_async(ws.as_str()).await.expect("connects");
    assert_eq!(next(&mut watcher).await["commands"], false);
    watcher
        .send(Message::Text(r#"{"cmd":"stop"}"#.into()))
        .await
        .expect("sends");
    let mut refused = false;
    for _ in 0..20 {
        let m = next(&mut watcher).await;
        if m["type"] == "refused" {
            assert_eq!(m["why"], "watching only: commands need the token");
            refused = true;
            break;
        }
    }
    assert!(refused, "the command was refused");
    assert_ne!(state_after(&mut watcher, 10).await, "ERROR", "and did nothing");
    let (mut operator, _) = tokio_tungstenite::connect_async(format!("{ws}?token=s3cret"))
        .await
        .expect("connects");
    assert_eq!(next(&mut operator).await["commands"], true);
    operator
        .send(Message::Text(r#"{"cmd":"stop"}"#.into()))
        .await
        .expect("sends");
    assert_eq!(state_after(&mut watcher, 10).await, "ERROR", "the operator's STOP");
}

#[test]
fn serving_beyond_loopback_needs_a_token() {
    let o = common::pkm(&["run", "--machine", "ox-x", "--hmi", "0.0.0.0:0", "--duration", "1"]);
    assert_eq!(o.status.code(), Some(2), "{}", common::stderr(&o));
    assert!(
        common::stderr(&o).contains(
            "--hmi 0.0.0.0:0: serving the screen beyond this computer needs a token (--hmi-token TOKEN or --hmi-token-file FILE)"
        ),
        "{}",
        common::stderr(&o)
    );
}
