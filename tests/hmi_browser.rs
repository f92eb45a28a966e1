//! The operator's screen end to end, in real time: the soft-PLC serves it (`run --hmi`), a
//! headless Chromium (Debian's `chromium`; `.ci/run` installs it where missing) loads the page,
//! sees INIT then READY, holds a jog button and sees the tool move, releases it and sees it stop,
//! presses STOP and sees ERROR with its reason, acknowledges and sees INIT. A second test drops a
//! WebSocket mid-jog and sees the jog stop (within a main cycle on a quiet machine).
//!
//! Without a Chromium the browser tests are skipped, and say so past the test harness's capture
//! (`common::skip`); under `.ci/run`, which installs one, they fail instead.

#[path = "common/mod.rs"]
mod common;

use std::process::Command;
use std::time::{Duration, Instant};

use common::cdp::{Browser, Page, chromium};
use futures::StreamExt;

/// Why a browser test cannot run here.
const NO_CHROMIUM: &str = "no Chromium here (apt-get install chromium)";

/// The Chromium to drive, or `None` once the test `name` has said why it skips.
fn chromium_or_skip(name: &str) -> Option<std::path::PathBuf> {
    let found = chromium();
    if found.is_none() {
        common::skip(name, NO_CHROMIUM);
    }
    found
}

/// At most two tests at once, whatever libtest's thread count: each runs a PLC in real time and
/// most a browser, which take little CPU (the eight tests: 12 CPU-seconds in 51 s one at a time)
/// but come in bursts; two side by side leave a 2-core machine room for those bursts (and for
/// CI's clippy at the lowest priority), more would starve each other on a small machine.
static SIDE_BY_SIDE: tokio::sync::Semaphore = tokio::sync::Semaphore::const_new(2);

/// A place among the tests that run at once, held until dropped.
async fn take_turn() -> tokio::sync::SemaphorePermit<'static> {
    SIDE_BY_SIDE.acquire().await.expect("the semaphore is never closed")
}

/// A running `pkm-plc run` with its screen, killed when dropped.
struct Plc {
    run: common::Logged,
    url: String,
}

impl Plc {
    /// The log so far.
    fn log(&self) -> String {
        self.run.log()
    }

    /// Stops the run as a service manager would (SIGTERM) and waits for its end: a run that
    /// does not end with success fails the test, with its log.
    fn stop(&mut self) {
        let stopped = Command::new("kill")
            .args(["-TERM", &self.run.child.id().to_string()])
            .status()
            .expect("kill runs");
        assert!(stopped.success());
        assert!(self.run.wait().success(), "{}", self.log());
    }

    /// The screen's port.
    fn port(&self) -> u16 {
        self.url
            .trim_end_matches('/')
            .rsplit(':')
            .next()
            .and_then(|p| p.parse().ok())
            .expect("a port in the screen's address")
    }
}

/// The O-X glide's configuration for these tests, written to `dir` (see
/// [`common::ox_config`]).
fn test_config(dir: &std::path::Path) -> std::path::PathBuf {
    common::ox_config(dir, false, |_| {})
}

/// As [`test_config`], READY after about 5 s instead of 11.65 s ([`common::ox_config`]).
fn quick_config(dir: &std::path::Path) -> std::path::PathBuf {
    common::ox_config(dir, true, |_| {})
}

/// Starts `pkm-plc run` in real time on the configuration `config` with the screen on a free
/// loopback port (and `more` arguments); returns when the screen's address is logged.
fn start_plc(config: &std::path::Path, seconds: u32, more: &[&str]) -> Plc {
    let mut command = common::pkm_command();
    command
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
        .env("RUST_LOG", "info");
    let (run, url) = common::Logged::start(command, "operator screen at ", Duration::from_secs(30));
    Plc { run, url }
}

/// Where the page's boxes are: the place and size (px) of each shown section that begins within
/// the first 800 px (what a 1280 × 800 screen shows; those further down are laid out only once
/// scrolled to, `content-visibility: auto`), in the page's order.
const LAYOUT: &str = "Array.from(document.querySelectorAll('main > section')).filter(s => !s.hidden && s.getBoundingClientRect().top < 800).map(s => { const r = s.getBoundingClientRect(); return `${s.id || s.querySelector('h2')?.textContent}: ${Math.round(r.left)},${Math.round(r.top)} ${Math.round(r.width)}x${Math.round(r.height)}`; }).join('; ')";

/// A text of the page: the value of a JavaScript expression.
async fn text(page: &Page, expression: &str) -> String {
    match page.evaluate(expression).await {
        Ok(serde_json::Value::String(text)) => text,
        _ => String::new(),
    }
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

/// The centre of the element `selector`, scrolled into view, once the page's layout has settled:
/// a part that appears above it when the server's answer comes (a program's path after a load)
/// moves it, and a hand would press where it is then, not where it was.
async fn centre(page: &Page, selector: &str) -> (f64, f64) {
    let read = async || -> (f64, f64) {
        let r: Vec<f64> = page
            .evaluate(format!(
                "(() => {{ const e = document.querySelector({selector:?}); e.scrollIntoView({{block: 'center'}}); const r = e.getBoundingClientRect(); return [r.x + r.width / 2, r.y + r.height / 2]; }})()"
            ))
            .await
            .ok()
            .and_then(|r| serde_json::from_value(r).ok())
            .unwrap_or_else(|| panic!("{selector}: no such element to click"));
        (r[0], r[1])
    };
    let mut at = read().await;
    let start = Instant::now();
    loop {
        tokio::time::sleep(Duration::from_millis(150)).await;
        let now = read().await;
        if now == at || start.elapsed() > Duration::from_secs(5) {
            return now;
        }
        at = now;
    }
}

/// Presses (or releases) the mouse's left button at `at`, as a hand on the page would.
async fn mouse(page: &Page, at: (f64, f64), pressed: bool) {
    page.mouse(at, pressed).await.expect("the mouse event is dispatched");
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
    let Some(chromium) =
        chromium_or_skip("hmi_browser::the_page_shows_referencing_jogs_while_held_stops_and_acknowledges")
    else {
        return;
    };
    let _turn = take_turn().await;
    let profile = tempfile::tempdir().expect("tempdir");
    let trace = profile.path().join("screen.jsonl");
    // The browser first: a cold start on a busy machine takes seconds, and the page must load
    // while the machine still references.
    let browser = launch(chromium, profile.path(), &[]).await;
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
    // Nothing on the screen moves when the state changes: every box keeps its place and size
    // from INIT (with the mechanism and the program's path drawn) to READY.
    until(&page, Duration::from_secs(10), "the program's path drawn in INIT", async |p| {
        text(p, "String(!document.getElementById('path-box').hidden && !document.getElementById('mechanism-box').hidden && document.getElementById('mechanism-note').textContent.startsWith('Not referenced'))").await == "true"
    })
    .await;
    let in_init = text(&page, LAYOUT).await;
    assert_eq!(state(&page).await, "INIT", "the layout taken in INIT");
    until(&page, Duration::from_secs(60), "READY shown", async |p| {
        state(p).await == "READY"
    })
    .await;
    assert_eq!(text(&page, LAYOUT).await, in_init, "the boxes moved from INIT to READY");
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
    // The name shows at once, the text once the page has asked the server for it.
    until(&page, Duration::from_secs(5), "its text shown", async |p| {
        text(p, "document.getElementById('program-text').textContent")
            .await
            .contains("O-X GLIDE")
    })
    .await;
    // And its path drawn (above the jog buttons: they move down when it shows).
    until(&page, Duration::from_secs(5), "its path shown", async |p| {
        text(p, "String(!document.getElementById('path-box').hidden)").await == "true"
    })
    .await;
    // Hold +x: the tool moves while held.
    let before = x(&page).await;
    // The +x button (the first pose coordinate).
    let button = centre(&page, r#".jog-btn[data-axis="1"][data-x="1"]"#).await;
    mouse(&page, button, true).await;
    let start = Instant::now();
    while x(&page).await <= before + 2.0 {
        let log = plc.run.log();
        let tail: Vec<&str> = log.lines().rev().take(30).collect();
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "the tool does not move (x {} from {before}, the page shows {:?}); the run's last lines:\n{}",
            x(&page).await,
            state(&page).await,
            tail.into_iter().rev().collect::<Vec<_>>().join("\n")
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // Still held: MOTION (on a busy machine a refresh of the held jog may come later than the
    // screen's dead-man allows, and the jog pauses for a frame: it goes on with the next).
    until(&page, Duration::from_secs(5), "MOTION while held", async |p| {
        state(p).await == "MOTION"
    })
    .await;
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
    // STOP: ERROR with its reason; Acknowledge clicked at once takes effect after the lockout: INIT.
    click(&page, "#stop").await;
    until(&page, Duration::from_secs(5), "ERROR shown", async |p| {
        state(p).await == "ERROR"
    })
    .await;
    assert_eq!(
        text(&page, "document.getElementById('reason').textContent").await,
        "STOP"
    );
    click(&page, "#ack").await;
    until(
        &page,
        Duration::from_secs(5),
        "INIT after the acknowledgement",
        async |p| matches!(state(p).await.as_str(), "REBOOT" | "INIT"),
    )
    .await;
    browser.close().await;
    // The screen's commands are inputs like the panel's: in the trace, and replayed.
    plc.stop();
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
async fn a_websocket_dropped_mid_jog_stops_the_jog() {
    use futures::SinkExt;
    use tokio_tungstenite::tungstenite::Message;
    let _turn = take_turn().await;
    let dir = tempfile::tempdir().expect("tempdir");
    let plc = start_plc(&quick_config(dir.path()), 60, &[]);
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
    // Why the watcher's connection ended, for a failure's message.
    let (ended_tx, ended) = tokio::sync::oneshot::channel::<String>();
    tokio::spawn(async move {
        let why = loop {
            // Ends with the connection (the PLC ends with the test).
            let f = match watcher.next().await {
                Some(Ok(Message::Text(t))) => match serde_json::from_str::<serde_json::Value>(&t) {
                    Ok(f) => f,
                    Err(e) => break format!("a frame that is not JSON ({e}): {t}"),
                },
                Some(Ok(Message::Close(c))) => break format!("closed by the screen: {c:?}"),
                Some(Ok(_)) => continue,
                Some(Err(e)) => break format!("error: {e}"),
                None => break "the stream ended".to_string(),
            };
            let entry = (
                Instant::now(),
                f["seq"].as_u64().unwrap_or(0),
                f["image"][jog].as_f64().unwrap_or(f64::NAN),
                f["state"].as_str().unwrap_or("").to_string(),
            );
            if tx.send(entry).is_err() {
                break "the test stopped listening".to_string();
            }
        };
        let _ = ended_tx.send(why);
    });
    // READY first.
    let start = Instant::now();
    let mut last = String::new();
    loop {
        let Some((_, _, _, state)) = rx.recv().await else {
            let why = ended.await.unwrap_or_default();
            panic!(
                "the frames ended in {last} before READY ({why}); the log:\n{}",
                plc.log()
            );
        };
        if state == "READY" {
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "READY in time; the log:\n{}",
            plc.log()
        );
        last = state;
    }
    // Jog, refreshed every 20 ms, until five frames in a row show it moving the machine (on a
    // busy machine a refresh may come late, and the screen's dead-man then stops the jog for a
    // frame: the drop must come in the middle of a jog).
    let (mut moving, start) = (0, Instant::now());
    while moving < 5 {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "no jog in 30 s; the log:\n{}",
            plc.log()
        );
        jogger
            .send(Message::Text(r#"{"cmd":"jog","x":1,"y":0}"#.into()))
            .await
            .expect("sends");
        tokio::time::sleep(Duration::from_millis(20)).await;
        while let Ok((_, _, x, state)) = rx.try_recv() {
            moving = if x == 1.0 && state == "MOTION" { moving + 1 } else { 0 };
        }
    }
    // The connection drops (no close frame).
    drop(jogger);
    let dropped = Instant::now();
    tokio::time::sleep(Duration::from_millis(500)).await;
    let mut frames = Vec::new();
    while let Ok(f) = rx.try_recv() {
        frames.push(f);
    }
    let after: Vec<&(Instant, u64, f64, String)> = frames.iter().filter(|f| f.0 >= dropped).collect();
    let stopped = after
        .iter()
        .position(|f| f.2 == 0.0)
        .expect("the jog stopped after the drop");
    assert!(after[stopped..].iter().all(|f| f.2 == 0.0), "and stayed stopped");
    let delay = after[stopped].0 - dropped;
    // One main cycle (50 ms) and the frame's way to this client on a quiet machine: a figure
    // for the docs. The bound asserted is what tells a jog stopped by the drop from one that runs
    // on: a busy machine delays frames, never by seconds.
    eprintln!("the jog read 0 in a frame {} ms after the drop", delay.as_millis());
    assert!(delay < Duration::from_secs(1), "{} ms", delay.as_millis());
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
    let _turn = take_turn().await;
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

/// Starts headless Chromium with its profile in `dir` and the switches `args` (name, value)
/// besides the usual.
async fn launch(chromium: std::path::PathBuf, dir: &std::path::Path, args: &[(&str, &str)]) -> Browser {
    Browser::launch(&chromium, &dir.join("profile"), args)
        .await
        .unwrap_or_else(|e| panic!("Chromium starts: {e}"))
}

/// Serves `html` to every request on a free loopback port (another origin than the screen's).
fn serve_page(html: String) -> u16 {
    use std::io::{Read, Write};
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("a port");
    let port = listener.local_addr().expect("address").port();
    std::thread::spawn(move || {
        for mut s in listener.incoming().flatten() {
            let mut request = [0u8; 4096];
            let _ = s.read(&mut request);
            let _ = write!(
                s,
                "HTTP/1.1 200 OK\r\nContent-Type: text/html\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{html}",
                html.len()
            );
        }
    });
    port
}

/// Every frame a watching client receives, as it arrives: (state, HMI_STOP, HMI_JOG_X).
async fn watch_frames(ws_url: &str) -> tokio::sync::mpsc::UnboundedReceiver<(String, bool, f64)> {
    use tokio_tungstenite::tungstenite::Message;
    let (mut watcher, _) = tokio_tungstenite::connect_async(ws_url).await.expect("connects");
    let hello = next(&mut watcher).await;
    let at = |name: &str| {
        hello["variables"]
            .as_array()
            .expect("variables")
            .iter()
            .position(|p| p[0] == name)
            .unwrap_or_else(|| panic!("{name} in the image"))
    };
    let (stop, jog) = (at("HMI_STOP"), at("HMI_JOG_X"));
    let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
    tokio::spawn(async move {
        while let Some(Ok(m)) = watcher.next().await {
            let Message::Text(t) = m else { continue };
            let f: serde_json::Value = serde_json::from_str(&t).expect("JSON");
            if f["type"] != "frame" {
                continue;
            }
            let entry = (
                f["state"].as_str().unwrap_or("").to_string(),
                f["image"][stop].as_bool().unwrap_or(false),
                f["image"][jog].as_f64().unwrap_or(f64::NAN),
            );
            if tx.send(entry).is_err() {
                break;
            }
        }
    });
    rx
}

/// Waits for a frame in `state` (at most `within`); `log` is the PLC's, shown if it never comes.
async fn until_state(
    rx: &mut tokio::sync::mpsc::UnboundedReceiver<(String, bool, f64)>,
    state: &str,
    within: Duration,
    log: impl Fn() -> String,
) {
    let start = Instant::now();
    let mut last = String::new();
    loop {
        let (s, _, _) = tokio::time::timeout(within, rx.recv())
            .await
            .unwrap_or_else(|_| panic!("no frame within {within:?}; the PLC's log:\n{}", log()))
            .expect("frames");
        if s == state {
            return;
        }
        assert!(
            start.elapsed() < within,
            "{state} not within {within:?}: the page shows {s} (before: {last}); the PLC's log:\n{}",
            log()
        );
        last = s;
    }
}

/// Any web page the operator has open could open the screen's WebSocket (loopback,
/// no token) and stop, jog or start programs. A page of another origin is refused before the
/// upgrade, and so is a page that reached the port under its own name (DNS rebinding, here
/// through Chromium's host resolver rules): nothing it sends reaches the process image.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_page_of_another_origin_or_a_rebound_name_reaches_nothing() {
    let Some(chromium) = chromium_or_skip("hmi_browser::a_page_of_another_origin_or_a_rebound_name_reaches_nothing")
    else {
        return;
    };
    let _turn = take_turn().await;
    let dir = tempfile::tempdir().expect("tempdir");
    let browser = launch(
        chromium,
        dir.path(),
        &[("host-resolver-rules", "MAP evil.test 127.0.0.1")],
    )
    .await;
    let page = browser.new_page("about:blank").await.expect("a page");
    let plc = start_plc(&quick_config(dir.path()), 90, &[]);
    let port = plc.port();
    let mut frames = watch_frames(&(plc.url.replacen("http://", "ws://", 1) + "ws")).await;
    // Referencing (INIT) is as good a time to attack as READY: a STOP that got through would
    // show as ERROR in either, and the test need not wait for the end of referencing.
    until_state(&mut frames, "INIT", Duration::from_secs(60), || plc.log()).await;
    // The attacker's page: opens the screen's WebSocket by its address and under its own name,
    // and sends STOP and a jog every 20 ms on whichever opens.
    let attack = |url: String| {
        format!(
            r#"(() => {{ const ws = new WebSocket("{url}"); window.results = window.results || {{}};
                ws.onopen = () => {{ window.results["{url}"] = "open"; setInterval(() => {{ ws.send('{{"cmd":"stop"}}'); ws.send('{{"cmd":"jog","x":1,"y":0}}'); }}, 20); }};
                ws.onclose = () => {{ window.results["{url}"] = window.results["{url}"] || "refused"; }}; }})()"#
        )
    };
    let scripts = [
        attack(format!("ws://127.0.0.1:{port}/ws")),
        attack(format!("ws://localhost:{port}/ws")),
        attack(format!("ws://evil.test:{port}/ws")),
    ];
    let html = format!(
        "<html><body>a page of another origin<script>{}</script></body></html>",
        scripts.join(";")
    );
    let other = serve_page(html);
    page.goto(format!("http://127.0.0.1:{other}/"))
        .await
        .expect("the other page loads");
    let results = async |p: &Page| text(p, "JSON.stringify(window.results || {})").await;
    until(
        &page,
        Duration::from_secs(10),
        "the attacker's sockets settle",
        async |p| results(p).await.matches("refused").count() + results(p).await.matches("open").count() == 3,
    )
    .await;
    assert_eq!(
        results(&page).await.matches("refused").count(),
        3,
        "{}",
        results(&page).await
    );
    // Seconds of the page trying: no ERROR (a STOP would be one), the screen's inputs never
    // moved.
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(2) {
        let (state, stop, jog) = frames.recv().await.expect("frames");
        assert!(
            matches!(state.as_str(), "INIT" | "READY") && !stop && jog == 0.0,
            "the other page reached the machine: {state}, STOP {stop}, jog {jog}; the PLC's log:\n{}",
            plc.log()
        );
    }
    // The rebound name does not even get the page.
    page.goto(format!("http://evil.test:{port}/")).await.expect("loads");
    assert!(
        text(&page, "document.body.innerText")
            .await
            .contains("this screen answers to its IP address or localhost"),
        "{}",
        text(&page, "document.body.innerText").await
    );
    let log = plc.log();
    assert!(
        log.contains("WebSocket refused: a page of another origin (http://127.0.0.1:"),
        "{log}"
    );
    assert!(log.contains(r#"refused a request for Host "evil.test:"#), "{log}");
    browser.close().await;
}

/// With a token, a page opened without it shows every control disabled; opened with it, the
/// token leaves the address bar (the server keeps it in an HttpOnly, SameSite cookie) and a
/// reload without it in the address still commands.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_watching_page_shows_its_controls_disabled_and_the_token_leaves_the_address() {
    let Some(chromium) =
        chromium_or_skip("hmi_browser::a_watching_page_shows_its_controls_disabled_and_the_token_leaves_the_address")
    else {
        return;
    };
    let _turn = take_turn().await;
    let dir = tempfile::tempdir().expect("tempdir");
    let browser = launch(chromium, dir.path(), &[]).await;
    let page = browser.new_page("about:blank").await.expect("a page");
    let token = "0123456789abcdef-token";
    let plc = start_plc(&test_config(dir.path()), 60, &["--hmi-token", token]);
    let controls = "[...document.querySelectorAll('button, select, .overrides input')]";
    // After the hello (`data-commands` set): every control disabled, or every one enabled.
    let all_disabled = format!(
        "String(document.body.dataset.commands === 'false' && {controls}.length > 5 && {controls}.every(b => b.disabled))"
    );
    let all_enabled = format!(
        "String(document.body.dataset.commands === 'true' && {controls}.length > 5 && {controls}.every(b => !b.disabled))"
    );
    page.goto(plc.url.as_str()).await.expect("loads");
    until(
        &page,
        Duration::from_secs(20),
        "a watching page's controls disabled",
        async |p| text(p, &all_disabled).await == "true",
    )
    .await;
    assert!(
        text(&page, "document.getElementById('access').textContent")
            .await
            .contains("watching only")
    );
    page.goto(format!("{}?token={token}", plc.url)).await.expect("loads");
    until(
        &page,
        Duration::from_secs(20),
        "the operator's controls enabled",
        async |p| text(p, &all_enabled).await == "true",
    )
    .await;
    assert_eq!(text(&page, "location.search").await, "", "the token left the address");
    page.reload().await.expect("reloads");
    until(
        &page,
        Duration::from_secs(20),
        "still commanding after a reload",
        async |p| text(p, &all_enabled).await == "true",
    )
    .await;
    browser.close().await;
}

/// One HTTP/1.1 GET of `path` with `host` as its Host header; the response's head and body.
fn get(port: u16, path: &str, host: &str) -> String {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).expect("connects");
    s.set_read_timeout(Some(Duration::from_secs(10))).expect("timeout");
    write!(s, "GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n").expect("sends");
    let mut response = String::new();
    let _ = s.read_to_string(&mut response);
    response
}

/// The screen as an attacker without a browser meets it: a foreign Host is 403 on every path,
/// every response forbids framing, a WebSocket with a foreign Origin is 403, a third client
/// beyond `--hmi-max-clients 2` is 503, an oversized message ends its connection, a flood of
/// messages is cut to the rate, a command with a stray field is refused; the token counts in a
/// bearer header too.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_screen_bounds_clients_messages_and_rates_and_checks_host_and_origin() {
    use futures::SinkExt;
    use tokio_tungstenite::tungstenite::Message;
    use tokio_tungstenite::tungstenite::client::IntoClientRequest;
    let _turn = take_turn().await;
    let dir = tempfile::tempdir().expect("tempdir");
    let token = "0123456789abcdef-token";
    let plc = start_plc(
        &test_config(dir.path()),
        60,
        &["--hmi-max-clients", "2", "--hmi-token", token],
    );
    let port = plc.port();
    for path in ["/", "/app.js", "/ws"] {
        let r = get(port, path, &format!("evil.example:{port}"));
        assert!(r.starts_with("HTTP/1.1 403"), "{path}: {r}");
    }
    let page = get(port, "/", &format!("127.0.0.1:{port}"));
    assert!(page.starts_with("HTTP/1.1 200"), "{page}");
    let head = page.to_ascii_lowercase();
    assert!(
        head.contains("x-frame-options: deny") && head.contains("content-security-policy: frame-ancestors 'none'"),
        "{page}"
    );
    assert!(!head.contains("set-cookie"), "no cookie without the token");
    let with_token = get(port, &format!("/?token={token}"), &format!("127.0.0.1:{port}")).to_ascii_lowercase();
    assert!(
        with_token.contains(&format!(
            "set-cookie: pkm_token={token}; path=/; httponly; samesite=strict"
        )),
        "{with_token}"
    );
    let ws = plc.url.replacen("http://", "ws://", 1) + "ws";
    let request = |origin: Option<&str>, bearer: Option<&str>| {
        let mut r = ws.as_str().into_client_request().expect("a request");
        if let Some(o) = origin {
            r.headers_mut().insert("Origin", o.parse().expect("a header"));
        }
        if let Some(t) = bearer {
            r.headers_mut()
                .insert("Authorization", format!("Bearer {t}").parse().expect("a header"));
        }
        r
    };
    let refused = tokio_tungstenite::connect_async(request(Some("http://evil.example"), None)).await;
    assert!(
        matches!(&refused, Err(tokio_tungstenite::tungstenite::Error::Http(r)) if r.status() == 403),
        "{refused:?}"
    );
    // The screen's own origin, with the token as a bearer header: commands.
    let (mut operator, _) =
        tokio_tungstenite::connect_async(request(Some(&format!("http://127.0.0.1:{port}")), Some(token)))
            .await
            .expect("connects");
    let hello = next(&mut operator).await;
    assert_eq!(hello["commands"], true);
    // Bounded: the hello does not carry the programs' text.
    assert!(hello.to_string().len() < 64 * 1024, "{} bytes", hello.to_string().len());
    assert!(hello["programs"][0].get("text").is_none());
    let (mut second, _) = tokio_tungstenite::connect_async(ws.as_str()).await.expect("connects");
    let third = tokio_tungstenite::connect_async(ws.as_str()).await;
    assert!(
        matches!(&third, Err(tokio_tungstenite::tungstenite::Error::Http(r)) if r.status() == 503),
        "{third:?}"
    );
    // A command with a stray field is not a command.
    operator
        .send(Message::Text(r#"{"cmd":"stop","force":true}"#.into()))
        .await
        .expect("sends");
    let refusal = loop {
        let m = next(&mut operator).await;
        if m["type"] == "refused" {
            break m;
        }
    };
    assert!(
        refusal["why"].as_str().unwrap_or("").contains("unknown field `force`"),
        "{refusal}"
    );
    // A flood of reads (300 at once): about the budget of 100 is answered.
    for _ in 0..300 {
        operator
            .send(Message::Text(r#"{"cmd":"text","program":1,"from":1}"#.into()))
            .await
            .expect("sends");
    }
    operator
        .send(Message::Text(r#"{"cmd":"path","program":99}"#.into()))
        .await
        .expect("sends");
    let mut answered = 0;
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(3) {
        let Ok(m) = tokio::time::timeout(Duration::from_millis(500), next(&mut operator)).await else {
            break;
        };
        if m["type"] == "text" {
            answered += 1;
            assert!(m["lines"].as_array().is_some_and(|l| l.len() <= 400));
        }
    }
    assert!((90..=200).contains(&answered), "{answered} of 300 answered");
    // An oversized message (64 KiB) ends the connection.
    let _ = second.send(Message::Text("x".repeat(64 * 1024).into())).await;
    let ended = tokio::time::timeout(Duration::from_secs(5), async {
        loop {
            match second.next().await {
                Some(Ok(_)) => continue,
                _ => return,
            }
        }
    })
    .await;
    assert!(ended.is_ok(), "the oversized message's connection still runs");
    drop(operator);
    tokio::time::sleep(Duration::from_millis(300)).await;
    let log = plc.log();
    assert!(log.contains("more than 100 messages a second"), "{log}");
    assert!(log.contains("messages over the rate"), "{log}");
}

/// The watch table's value of the process-image variable `name`.
async fn watched(page: &Page, name: &str) -> String {
    text(
        page,
        &format!(
            "(document.querySelector('#watch tr[data-name=\"{}\"] td:last-child') || {{}}).textContent || ''",
            name.to_lowercase()
        ),
    )
    .await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_screen_sets_the_overrides_steps_a_program_line_by_line_runs_mdi_and_runs_from_a_line() {
    let Some(chromium) = chromium_or_skip(
        "hmi_browser::the_screen_sets_the_overrides_steps_a_program_line_by_line_runs_mdi_and_runs_from_a_line",
    ) else {
        return;
    };
    let _turn = take_turn().await;
    let dir = tempfile::tempdir().expect("tempdir");
    let programs = dir.path().join("programs");
    std::fs::create_dir(&programs).expect("a directory");
    // Three lines of motion from the reference pose (the program's start), then back.
    std::fs::write(
        programs.join("steps.ngc"),
        "G21 G90 G64 P0.01\nG1 X4 F600\nY4\nX0\nG0 Y0\nM2\n",
    )
    .expect("the program");
    let trace = dir.path().join("screen.jsonl");
    let browser = launch(chromium, dir.path(), &[]).await;
    let page = browser.new_page("about:blank").await.expect("a page");
    let config = quick_config(dir.path());
    let mut plc = start_plc(
        &config,
        120,
        &[
            "--programs",
            programs.to_str().expect("utf-8"),
            "--trace",
            trace.to_str().expect("utf-8"),
        ],
    );
    page.goto(plc.url.as_str()).await.expect("loads");
    until(&page, Duration::from_secs(60), "READY shown", async |p| {
        state(p).await == "READY"
    })
    .await;
    // Without a touch of the sliders the PLC runs at 100 %.
    assert_eq!(watched(&page, "NC_FEED_OVERRIDE").await, "100");
    assert_eq!(watched(&page, "NC_RAPID_OVERRIDE").await, "100");
    // The sliders as a hand moves them: the PLC takes their values.
    for (id, value) in [("feed-override", 50), ("rapid-override", 30)] {
        page.evaluate(format!(
            "(() => {{ const s = document.getElementById('{id}'); s.value = {value}; s.dispatchEvent(new Event('input')); }})()"
        ))
        .await
        .expect("the slider moves");
    }
    until(&page, Duration::from_secs(5), "the overrides in the PLC", async |p| {
        watched(p, "NC_FEED_OVERRIDE").await == "50" && watched(p, "NC_RAPID_OVERRIDE").await == "30"
    })
    .await;
    assert_eq!(
        text(&page, "document.getElementById('feed-value').textContent").await,
        "50 %"
    );
    // Single block on, then start: the program stands after its first line.
    click(&page, "#single-block").await;
    until(&page, Duration::from_secs(5), "single block in the PLC", async |p| {
        watched(p, "NC_SINGLE_BLOCK").await == "true"
    })
    .await;
    // From here the page counts the server's frames it takes and the animation frames it asks
    // the browser for: one drawing per frame, however much moved (each drawing costs a
    // software-rendering browser a few ms).
    page.evaluate(
        "(() => { window.framesTaken = 0; window.animationFrames = 0; \
         const take0 = take; take = (m) => { window.framesTaken++; take0(m); }; \
         const raf = window.requestAnimationFrame.bind(window); \
         window.requestAnimationFrame = (f) => { window.animationFrames++; return raf(f); }; })()",
    )
    .await
    .expect("the counters");
    click(&page, "#nc-start").await;
    let note = async |p: &Page| text(p, "document.getElementById('note').textContent").await;
    let stands = "single block: the line is done; NC_RESUME runs the next";
    for line in ["3", "4"] {
        until(&page, Duration::from_secs(20), "standing after a line", async |p| {
            note(p).await == stands && watched(p, "NC_LINE").await == line
        })
        .await;
        assert_eq!(state(&page).await, "AUTO");
        click(&page, "#nc-resume").await;
    }
    // Single block off: a resume runs the rest.
    until(
        &page,
        Duration::from_secs(20),
        "standing before the last line",
        async |p| note(p).await == stands && watched(p, "NC_LINE").await == "5",
    )
    .await;
    click(&page, "#single-block").await;
    click(&page, "#nc-resume").await;
    until(
        &page,
        Duration::from_secs(30),
        "READY at the program's end",
        async |p| state(p).await == "READY" && watched(p, "NC_COMPLETED").await == "true",
    )
    .await;
    let counted = page
        .evaluate("[window.framesTaken, window.animationFrames]")
        .await
        .expect("the counts");
    let (taken, drawn) = (counted[0].as_u64().unwrap_or(0), counted[1].as_u64().unwrap_or(0));
    assert!(taken >= 10, "frames taken while the program ran: {taken}");
    assert!(
        drawn <= taken,
        "{drawn} animation frames asked for {taken} frames taken"
    );
    // MDI: two lines typed, run from where the tool stands (the program's end, the origin).
    page.evaluate("document.getElementById('mdi-text').value = 'G1 X3 Y2 F600\\nG1 X3.5'")
        .await
        .expect("typed");
    click(&page, "#nc-mdi").await;
    let file = async |p: &Page| text(p, "document.getElementById('program-file').textContent").await;
    until(
        &page,
        Duration::from_secs(30),
        "the MDI lines run to their end",
        async |p| {
            watched(p, "NC_PROGRAM").await == "2"
                && state(p).await == "READY"
                && watched(p, "NC_COMPLETED").await == "true"
                && file(p).await == "MDI"
        },
    )
    .await;
    until(
        &page,
        Duration::from_secs(5),
        "the tool where the lines took it",
        async |p| (x(p).await - 3.5).abs() < 0.01 && (shown(p, "y").await - 2.0).abs() < 0.01,
    )
    .await;
    // An MDI line that cannot run says why, with its line and column, and nothing starts.
    page.evaluate("document.getElementById('mdi-text').value = 'G1 X5'")
        .await
        .expect("typed");
    click(&page, "#nc-mdi").await;
    until(&page, Duration::from_secs(10), "the refusal shown", async |p| {
        text(p, "document.getElementById('access').textContent").await
            == "MDI:1:4: no feed rate: an F word is needed before the first G1, G2 or G3"
    })
    .await;
    assert_eq!(watched(&page, "NC_PROGRAM").await, "2");
    // The program again, from its fourth line (X0): the tool goes to (4, 4) first.
    page.evaluate("document.getElementById('program-choice').value = '1'")
        .await
        .expect("chosen");
    click(&page, "#nc-load").await;
    until(&page, Duration::from_secs(5), "the program loaded", async |p| {
        file(p).await.ends_with("steps.ngc") && text(p, "String(!!document.getElementById('line-4'))").await == "true"
    })
    .await;
    click(&page, "#line-4").await;
    assert_eq!(text(&page, "document.getElementById('from-line').value").await, "4");
    click(&page, "#nc-from-line").await;
    until(
        &page,
        Duration::from_secs(30),
        "the program run from line 4 to its end",
        async |p| {
            watched(p, "NC_PROGRAM").await == "3"
                && state(p).await == "READY"
                && watched(p, "NC_COMPLETED").await == "true"
        },
    )
    .await;
    until(
        &page,
        Duration::from_secs(5),
        "the tool at the program's end",
        async |p| x(p).await.abs() < 0.01 && shown(p, "y").await.abs() < 0.01,
    )
    .await;
    // The chooser names the job loaded (it showed blank for a job not in its list).
    let chosen = "(() => { const c = document.getElementById('program-choice'); return c.options[c.selectedIndex]?.textContent || ''; })()";
    until(
        &page,
        Duration::from_secs(5),
        "the job named in the chooser",
        async |p| text(p, chosen).await.ends_with("steps.ngc from line 4"),
    )
    .await;
    // A page opened now draws what was cut: the server kept the run's path (from (3.5, 2) to
    // (4, 4), then around to the origin).
    let late = browser.new_page(plc.url.as_str()).await.expect("a second page");
    until(&late, Duration::from_secs(10), "the cut path on a late page", async |p| {
        text(p, "String(cut.length > 20 && Math.hypot(...cut[cut.length - 1].slice(0, 2)) < 0.05 && Math.hypot(cut[0][0] - 3.5, cut[0][1] - 2) < 0.1)").await == "true"
    })
    .await;
    // The DRO follows the program's coordinates while it runs: G55 (its origin at x 3, set by
    // the program) during the dwell, the tool at x 8 reading 5; G54 again once it has ended.
    // (On the page in front: a page behind another draws nothing.)
    late.evaluate("document.getElementById('mdi-text').value = 'G10 L2 P2 X3\\nG55 G0 X5\\nG4 P3'")
        .await
        .expect("typed");
    click(&late, "#nc-mdi").await;
    // The work system shown, and the work x less the machine x (the offset the DRO takes off).
    let dro = async |p: &Page| {
        let system = text(p, "document.getElementById('dro-system').textContent").await;
        let work: f64 = text(p, "document.getElementById('work-x').textContent")
            .await
            .parse()
            .unwrap_or(f64::NAN);
        (system, work, work - x(p).await)
    };
    until(&late, Duration::from_secs(30), "G55 on the DRO", async |p| {
        let (system, work, off) = dro(p).await;
        system == "G55" && (work - 5.0).abs() < 0.01 && (off + 3.0).abs() < 0.002
    })
    .await;
    until(
        &late,
        Duration::from_secs(30),
        "G54 again after the program",
        async |p| {
            let (system, work, off) = dro(p).await;
            state(p).await == "READY"
                && watched(p, "NC_COMPLETED").await == "true"
                && system == "G54"
                && (work - 8.0).abs() < 0.01
                && off.abs() < 0.002
        },
    )
    .await;
    browser.close().await;
    // The overrides and single block are inputs like the panel's: in the trace, and replayed.
    plc.stop();
    let recorded = std::fs::read_to_string(&trace).expect("the trace");
    for recorded_input in [
        r#""NC_FEED_OVERRIDE":50"#,
        r#""NC_RAPID_OVERRIDE":30"#,
        r#""NC_SINGLE_BLOCK":true"#,
        r#""mdi":"G1 X3 Y2 F600\nG1 X3.5""#,
        r#""from_line":{"program":1,"line":4}"#,
    ] {
        assert!(recorded.contains(recorded_input), "{recorded_input} in the trace");
    }
    common::assert_replays_identically(&trace, &["--config", config.to_str().expect("utf-8")]);
}

/// The manual tool change on the screen: the program stands at `T1 M6` and the page asks for
/// tool 1 with its comment from the tool table; the program's message (MSG) is shown; "Tool
/// changed" goes on. Then a touch-off moves G54, kept in the parameter file, and the program
/// planned again runs at the new origin. The run replays from its trace (which carries the tool
/// table and the job's offsets), and the program's messages are in the log.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_screen_asks_for_the_tool_of_a_manual_tool_change_and_shows_the_programs_message() {
    let Some(chromium) = chromium_or_skip(
        "hmi_browser::the_screen_asks_for_the_tool_of_a_manual_tool_change_and_shows_the_programs_message",
    ) else {
        return;
    };
    let _turn = take_turn().await;
    let dir = tempfile::tempdir().expect("tempdir");
    let program = dir.path().join("tools.ngc");
    std::fs::write(
        &program,
        "(MSG, clamp the part)\nT1 M6\nG43 H1\n(DEBUG, tool #5400 in, Z offset #5403)\nG1 X4 F600\nG0 X0\nM2\n",
    )
    .expect("the program");
    let table = dir.path().join("tool.tbl");
    std::fs::write(&table, "T1 P1 Z30 D6 ;6 mm end mill\n").expect("the table");
    let trace = dir.path().join("tools.jsonl");
    let var = dir.path().join("ox-x.var");
    let browser = launch(chromium, dir.path(), &[]).await;
    let page = browser.new_page("about:blank").await.expect("a page");
    let config = quick_config(dir.path());
    let mut plc = start_plc(
        &config,
        120,
        &[
            "--program",
            program.to_str().expect("utf-8"),
            "--tool-table",
            table.to_str().expect("utf-8"),
            "--var-file",
            var.to_str().expect("utf-8"),
            "--trace",
            trace.to_str().expect("utf-8"),
        ],
    );
    page.goto(plc.url.as_str()).await.expect("loads");
    let asked = async |p: &Page| {
        text(
            p,
            "document.getElementById('tool-change').hidden ? '' : document.getElementById('tool-ask').textContent",
        )
        .await
    };
    until(&page, Duration::from_secs(60), "the tool change asked for", async |p| {
        !asked(p).await.is_empty()
    })
    .await;
    assert_eq!(
        asked(&page).await,
        "Tool change: put tool 1 (6 mm end mill) in the spindle, then press Tool changed."
    );
    // The PLC's note names its signals (TOOL_PREP_NUMBER, TOOL_CHANGED): the prompt says it in
    // the operator's words instead.
    assert_eq!(text(&page, "document.getElementById('note').textContent").await, "");
    assert_eq!(state(&page).await, "AUTO");
    assert!(
        text(&page, "document.getElementById('message').textContent")
            .await
            .ends_with("clamp the part"),
        "the program's message shown"
    );
    // It stands: a second later the tool has not moved and the change still waits.
    tokio::time::sleep(Duration::from_secs(1)).await;
    until(&page, Duration::from_secs(5), "TOOL_CHANGE in the image", async |p| {
        watched(p, "TOOL_CHANGE").await == "true"
    })
    .await;
    assert!(x(&page).await.abs() < 0.01);
    click(&page, "#tool-changed").await;
    until(
        &page,
        Duration::from_secs(30),
        "the program done with tool 1",
        async |p| watched(p, "NC_COMPLETED").await == "true" && watched(p, "TOOL_NUMBER").await == "1",
    )
    .await;
    assert!(asked(&page).await.is_empty(), "the prompt is gone");
    // A finished program leaves nothing to go and no line to follow.
    until(&page, Duration::from_secs(10), "READY after the program", async |p| {
        state(p).await == "READY"
    })
    .await;
    for id in ["dtg", "progress-line"] {
        assert_eq!(
            text(&page, &format!("document.getElementById('{id}').textContent")).await,
            "–",
            "{id} after the program"
        );
    }
    // A value that rounds to zero has no sign.
    assert_eq!(
        page.evaluate("[num(-0.0004, 3), num(-0.0006, 3), num(-0.4, 0), num(0, 3)]")
            .await
            .expect("numbers"),
        serde_json::json!(["0.000", "-0.001", "0", "0.000"])
    );
    assert_eq!(
        text(&page, "document.getElementById('tool-in').textContent").await,
        "tool 1 (6 mm end mill) in the spindle"
    );
    // Touch-off: X reads 5 where the tool stands (the reference pose, after the program): G54's
    // origin moves to X −5, the parameter file keeps it, the program is planned again and
    // loaded; started, it runs 5 mm to the left and ends at X −5.
    until(&page, Duration::from_secs(10), "READY after the program", async |p| {
        state(p).await == "READY"
    })
    .await;
    page.evaluate("document.getElementById('touch-value').value = '5'")
        .await
        .expect("the value typed");
    click(&page, "#touch-off").await;
    let said = async |p: &Page| text(p, "document.getElementById('access').textContent").await;
    until(
        &page,
        Duration::from_secs(30),
        "the touch-off and the program planned again",
        async |p| said(p).await.contains("planned again and loaded"),
    )
    .await;
    assert_eq!(
        said(&page).await,
        format!(
            "G54 X = 5: origin 0.000 → -5.000 mm; {} from line 1 planned again and loaded",
            program.display()
        )
    );
    let kept = std::fs::read_to_string(&var).expect("the parameter file");
    assert!(kept.contains("5221\t-5.000000\n"), "{kept}");
    click(&page, "#nc-start").await;
    until(
        &page,
        Duration::from_secs(30),
        "the tool change asked again",
        async |p| !asked(p).await.is_empty(),
    )
    .await;
    click(&page, "#tool-changed").await;
    until(
        &page,
        Duration::from_secs(30),
        "the program done at the new origin",
        async |p| state(p).await == "READY" && (x(p).await + 5.0).abs() < 0.01,
    )
    .await;
    // ERROR ends what the page said before: the program's message and the touch-off's answer
    // give way to the reason and what to do.
    click(&page, "#stop").await;
    until(&page, Duration::from_secs(10), "ERROR after STOP", async |p| {
        state(p).await == "ERROR"
    })
    .await;
    assert_eq!(
        text(&page, "String(document.getElementById('message').hidden)").await,
        "true"
    );
    assert_eq!(said(&page).await, "");
    assert!(
        !text(&page, "document.getElementById('note').textContent")
            .await
            .is_empty(),
        "what to do in ERROR"
    );
    browser.close().await;
    plc.stop();
    let log = plc.log();
    assert!(log.contains("screen 127.0.0.1:"), "{log}");
    assert!(log.contains("tool change 1 confirmed: tool 1 in the spindle"), "{log}");
    assert!(log.contains("tool change 2 confirmed: tool 1 in the spindle"), "{log}");
    assert!(log.contains("NC line 1 (MSG): clamp the part"), "{log}");
    assert!(
        log.contains("NC line 4 (DEBUG): tool 1.000000 in, Z offset 30.000000"),
        "{log}"
    );
    common::assert_replays_identically(&trace, &["--config", config.to_str().expect("utf-8")]);
}

/// What a machine-tool user looks for first: the DRO (work and machine positions, marked as not
/// trustworthy before referencing), the spindle override, the incremental jog (a 1 mm step), the
/// 3-D view of the path, the mechanism kept and dimmed in ERROR with what to do next, and the
/// alarm history with who acknowledged. Screenshots for docs/hmi.md with PKM_SCREENSHOTS=DIR.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_screen_shows_a_dro_steps_the_jog_keeps_an_alarm_history_and_dims_the_mechanism_in_error() {
    let Some(chromium) = chromium_or_skip(
        "hmi_browser::the_screen_shows_a_dro_steps_the_jog_keeps_an_alarm_history_and_dims_the_mechanism_in_error",
    ) else {
        return;
    };
    let _turn = take_turn().await;
    let dir = tempfile::tempdir().expect("tempdir");
    let programs = dir.path().join("programs");
    std::fs::create_dir(&programs).expect("a directory");
    std::fs::write(
        programs.join("square.ngc"),
        "G0 X2 Y2\nG1 Z-1 F300\nG1 X8 F600\nY8\nX2\nY2\nG0 Z0\nG0 X0 Y0\nM2\n",
    )
    .expect("the program");
    let browser = launch(chromium, dir.path(), &[]).await;
    let page = browser.new_page("about:blank").await.expect("a page");
    let config = quick_config(dir.path());
    let mut plc = start_plc(&config, 120, &["--programs", programs.to_str().expect("utf-8")]);
    page.goto(plc.url.as_str()).await.expect("loads");
    // Before referencing the positions are marked as not trustworthy.
    until(&page, Duration::from_secs(30), "INIT shown", async |p| {
        state(p).await == "INIT"
    })
    .await;
    let untrusted = async |p: &Page| text(p, "String(document.body.classList.contains('untrusted'))").await;
    assert_eq!(untrusted(&page).await, "true");
    until(&page, Duration::from_secs(60), "READY shown", async |p| {
        state(p).await == "READY"
    })
    .await;
    until(&page, Duration::from_secs(5), "the positions trusted", async |p| {
        untrusted(p).await == "false"
    })
    .await;
    let work = async |p: &Page, a: &str| {
        text(p, &format!("document.getElementById('work-{a}').textContent"))
            .await
            .parse::<f64>()
            .unwrap_or(f64::NAN)
    };
    assert!(work(&page, "x").await.abs() < 0.01 && x(&page).await.abs() < 0.01);
    // The spindle override is an input like the feed override.
    page.evaluate("(() => { const s = document.getElementById('spindle-override'); s.value = 80; s.dispatchEvent(new Event('input')); })()")
        .await
        .expect("the slider moves");
    until(
        &page,
        Duration::from_secs(5),
        "the spindle override in the PLC",
        async |p| watched(p, "NC_SPINDLE_OVERRIDE").await == "80",
    )
    .await;
    // A 1 mm step along X: the tool goes 1 mm and stands (READY again).
    page.evaluate("(() => { const s = document.getElementById('jog-step'); s.value = '1'; })()")
        .await
        .expect("the step chosen");
    click(&page, r#".jog-btn[data-axis="1"][data-x="1"]"#).await;
    until(&page, Duration::from_secs(20), "the step made", async |p| {
        state(p).await == "READY" && (x(p).await - 1.0).abs() < 0.005
    })
    .await;
    assert!(
        (work(&page, "x").await - 1.0).abs() < 0.005,
        "the work position follows"
    );
    // The step was a job of its own (an MDI line): the program it replaced is loaded again
    // once it is done, not left as "MDI".
    let file = async |p: &Page| text(p, "document.getElementById('program-file').textContent").await;
    until(
        &page,
        Duration::from_secs(10),
        "the program loaded again after the step",
        async |p| file(p).await.ends_with("square.ngc") && watched(p, "NC_PROGRAM").await == "1",
    )
    .await;
    // A touch-off without a parameter file says that it lasts until the PLC stops only.
    page.evaluate("document.getElementById('touch-value').value = '1'")
        .await
        .expect("the value typed");
    click(&page, "#touch-off").await;
    let said = async |p: &Page| text(p, "document.getElementById('access').textContent").await;
    until(&page, Duration::from_secs(30), "the touch-off", async |p| {
        said(p).await.contains("planned again and loaded")
    })
    .await;
    let answer = said(&page).await;
    assert!(!answer.contains("-0.000"), "no signed zero: {answer}");
    assert!(
        answer.starts_with("G54 X = 1: origin 0.000 → ")
            && answer.contains(" mm, kept until the PLC stops only: no parameter file (--var-file, nc.var_file); "),
        "{answer}"
    );
    assert!(
        plc.log().contains(", kept until the PLC stops only: no parameter file"),
        "{}",
        plc.log()
    );
    // The 3-D view of the program's path: switched on, it draws.
    until(&page, Duration::from_secs(10), "the path box", async |p| {
        text(p, "String(!document.getElementById('path-box').hidden)").await == "true"
    })
    .await;
    click(&page, "#view3d").await;
    let drawn = "(() => { const c = document.getElementById('path'); const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; let n = 0; for (let i = 3; i < d.length; i += 4) if (d[i]) n++; return String(n > 200 && view3d.on); })()";
    until(&page, Duration::from_secs(5), "the 3-D view drawn", async |p| {
        text(p, drawn).await == "true"
    })
    .await;
    if let Some(shots) = std::env::var_os("PKM_SCREENSHOTS") {
        let shots = std::path::PathBuf::from(shots);
        page.screenshot(&shots.join("hmi-dro.png")).await.expect("a screenshot");
    }
    let history = async |p: &Page| {
        text(
            p,
            "Array.from(document.querySelectorAll('#alarms tr.alarm')).map(r => r.textContent).join(' | ')",
        )
        .await
    };
    // Reference: from READY the machine references again (REBOOT, INIT, READY), not an error;
    // refused while it references, with why.
    click(&page, "#reference").await;
    until(&page, Duration::from_secs(5), "referencing again", async |p| {
        state(p).await == "INIT"
    })
    .await;
    assert_eq!(
        untrusted(&page).await,
        "true",
        "the positions are not trusted while it references"
    );
    click(&page, "#reference").await;
    until(
        &page,
        Duration::from_secs(5),
        "the second Reference refused",
        async |p| {
            said(p)
                .await
                .starts_with("the machine references again from READY only")
        },
    )
    .await;
    until(&page, Duration::from_secs(60), "READY again", async |p| {
        state(p).await == "READY" && untrusted(p).await == "false"
    })
    .await;
    assert!(plc.log().contains("reference again"), "{}", plc.log());
    assert!(
        !history(&page).await.contains("error"),
        "referencing again is no error: {}",
        history(&page).await
    );
    // STOP: ERROR in the history; the mechanism stays, dimmed, with what to do next.
    click(&page, "#stop").await;
    until(&page, Duration::from_secs(5), "ERROR shown", async |p| {
        state(p).await == "ERROR"
    })
    .await;
    until(&page, Duration::from_secs(5), "the mechanism dimmed with a note", async |p| {
        text(p, "String(document.getElementById('mechanism-box').classList.contains('dimmed') && !document.getElementById('mechanism-box').hidden)").await == "true"
            && text(p, "document.getElementById('mechanism-note').textContent").await
                == "ERROR: the last pose drawn before it. Press Acknowledge, then reference the machine."
    })
    .await;
    if let Some(shots) = std::env::var_os("PKM_SCREENSHOTS") {
        let shots = std::path::PathBuf::from(shots);
        page.screenshot(&shots.join("hmi-error.png"))
            .await
            .expect("a screenshot");
    }
    click(&page, "#ack").await;
    until(
        &page,
        Duration::from_secs(10),
        "the acknowledgement in the history",
        async |p| history(p).await.contains("acknowledged"),
    )
    .await;
    // Acknowledged, the machine is not referenced: the mechanism stays dimmed and says why
    // (it showed the last referenced pose as trusted before).
    until(
        &page,
        Duration::from_secs(5),
        "the mechanism dimmed while not referenced",
        async |p| {
            text(
                p,
                "String(document.getElementById('mechanism-box').classList.contains('dimmed'))",
            )
            .await
                == "true"
                && text(p, "document.getElementById('mechanism-note').textContent").await
                    == "Not referenced: the last pose drawn before; drawn again once the machine is referenced."
        },
    )
    .await;
    let h = history(&page).await;
    assert!(h.contains("errorSTOP"), "{h}");
    assert!(h.contains("by screen 127.0.0.1:"), "{h}");
    // A page opened later gets the history.
    let late = browser.new_page(plc.url.as_str()).await.expect("a second page");
    until(
        &late,
        Duration::from_secs(10),
        "the history on a late page",
        async |p| history(p).await.contains("errorSTOP"),
    )
    .await;
    browser.close().await;
    plc.stop();
    assert!(plc.log().contains("step G91 G0 X1"), "{}", plc.log());
}

/// The simulation mode with the 3-D twin: the hexapod in `run --virtual --pace`, its screen
/// saying it shows a simulation; in 3-D the programmed path and the whole mechanism — struts,
/// platform, spindle — are in one scene at the machine's scale, every point inside the canvas
/// however the view is turned; as the tilted circle runs, the spindle tilts with the platform
/// (the tilt the flat path alone did not show). Screenshot `hmi-3d.png` with PKM_SCREENSHOTS.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_simulation_shows_the_machine_and_its_path_in_one_3d_scene() {
    let Some(chromium) = chromium_or_skip("hmi_browser::the_simulation_shows_the_machine_and_its_path_in_one_3d_scene")
    else {
        return;
    };
    let _turn = take_turn().await;
    let dir = tempfile::tempdir().expect("tempdir");
    let programs = dir.path().join("programs");
    std::fs::create_dir(&programs).expect("a directory");
    std::fs::copy(
        common::root().join("programs/hexapod-tilted-circle.ngc"),
        programs.join("hexapod-tilted-circle.ngc"),
    )
    .expect("copied");
    let browser = launch(chromium, dir.path(), &[]).await;
    let page = browser.new_page("about:blank").await.expect("a page");
    let mut command = common::pkm_command();
    command
        .args([
            "run",
            "--machine",
            "hexapod",
            "--virtual",
            "--pace",
            "5",
            "--hmi",
            "127.0.0.1:0",
        ])
        .args(["--opcua", "none", "--programs"])
        .arg(&programs)
        .env("RUST_LOG", "info");
    let (run, url) = common::Logged::start(command, "operator screen at ", Duration::from_secs(30));
    let mut plc = Plc { run, url };
    page.goto(plc.url.as_str()).await.expect("loads");
    until(&page, Duration::from_secs(10), "the simulation named", async |p| {
        text(
            p,
            "document.getElementById('simulation').hidden ? '' : document.getElementById('simulation').textContent",
        )
        .await
            == "simulation at 5× real time"
    })
    .await;
    until(&page, Duration::from_secs(60), "READY shown", async |p| {
        state(p).await == "READY"
    })
    .await;
    click(&page, "#view3d").await;
    click(&page, "#nc-start").await;
    until(&page, Duration::from_secs(20), "AUTO shown", async |p| {
        state(p).await == "AUTO"
    })
    .await;
    // Every point of the scene — the programmed path and the mechanism as it stands — inside
    // the canvas, at three turns of the view.
    let inside = "(() => { const c = document.getElementById('path'); const px = projection(c); const pts = programmed.concat((links || []).flat()); return String(links && links.length === 19 && pts.every(p => { const [x, y] = px(p); return x >= 0 && x <= c.width && y >= 0 && y <= c.height; })); })()";
    for (yaw, pitch) in [(-0.6, 0.9), (1.2, 0.3), (2.8, 1.5)] {
        page.evaluate(format!("view3d.yaw = {yaw}; view3d.pitch = {pitch}; redraw(true);"))
            .await
            .expect("the view turned");
        until(
            &page,
            Duration::from_secs(10),
            "the whole scene in the canvas",
            async |p| text(p, inside).await == "true",
        )
        .await;
    }
    page.evaluate("view3d.yaw = -0.6; view3d.pitch = 0.9; redraw(true);")
        .await
        .expect("turned back");
    // The mechanism stands where the path is: the spindle starts at the tool point the frames
    // report (both in the machine frame, home at the origin), within the frames' 50 ms apart.
    let apart = "(() => { const [a] = links[18]; const t = cut[cut.length - 1]; return String(Math.hypot(a[0] - t[0], a[1] - t[1], a[2] - t[2])); })()";
    until(
        &page,
        Duration::from_secs(10),
        "the spindle at the tool point",
        async |p| text(p, apart).await.parse::<f64>().unwrap_or(f64::MAX) < 2.0,
    )
    .await;
    // The spindle (the last link) tilts as the platform does: more than 2° off the vertical
    // at some frame of the circle.
    let tilt = "(() => { const [a, b] = links[18]; const d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]]; return String(Math.acos(d[2] / Math.hypot(...d)) * 180 / Math.PI); })()";
    until(&page, Duration::from_secs(60), "the spindle tilted", async |p| {
        text(p, tilt).await.parse::<f64>().unwrap_or(0.0) > 2.0
    })
    .await;
    if let Some(shots) = std::env::var_os("PKM_SCREENSHOTS") {
        let shots = std::path::PathBuf::from(shots);
        page.evaluate("document.getElementById('path-box').scrollIntoView()")
            .await
            .expect("scrolled");
        page.screenshot(&shots.join("hmi-3d.png")).await.expect("a screenshot");
    }
    plc.stop();
}

/// The tool table on the screen, as LinuxCNC's tool table editor: in READY an entry's offsets,
/// diameter and comment are saved to the file at once (whole, in LinuxCNC's format), a tool is
/// added and another removed, a wrong value is refused with why and changes nothing; the jobs
/// made after a change plan with the table as changed (an MDI `G43 H1` takes the new offset).
/// Screenshot `hmi-tools.png` with PKM_SCREENSHOTS.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_tool_table_is_edited_on_the_screen_and_written_to_its_file() {
    let Some(chromium) =
        chromium_or_skip("hmi_browser::the_tool_table_is_edited_on_the_screen_and_written_to_its_file")
    else {
        return;
    };
    let _turn = take_turn().await;
    let dir = tempfile::tempdir().expect("tempdir");
    let table = dir.path().join("tool.tbl");
    std::fs::write(&table, "T1 P1 Z0 D6 ;6 mm end mill\nT2 P2 Z0 D3 ;3 mm drill\n").expect("the table");
    let browser = launch(chromium, dir.path(), &[]).await;
    let page = browser.new_page("about:blank").await.expect("a page");
    let config = quick_config(dir.path());
    let trace = dir.path().join("tools.jsonl");
    let mut plc = start_plc(
        &config,
        120,
        &[
            "--tool-table",
            table.to_str().expect("utf-8"),
            "--trace",
            trace.to_str().expect("utf-8"),
        ],
    );
    page.goto(plc.url.as_str()).await.expect("loads");
    until(&page, Duration::from_secs(60), "READY shown", async |p| {
        state(p).await == "READY"
    })
    .await;
    let rows = "String(document.querySelectorAll('#tools tr[data-tool]').length)";
    assert_eq!(
        text(&page, rows).await,
        "2",
        "{}",
        text(&page, "JSON.stringify([toolTable, jobs])").await
    );
    // T1: Z 1.5 mm, diameter 6.35, another comment; saved.
    page.evaluate(
        "(() => { const r = document.querySelector('#tools tr[data-tool=\"1\"]'); r.querySelector('.offset[data-c=\"2\"]').value = '1.5'; r.querySelector('.diameter').value = '6.35'; r.querySelector('.comment').value = '1/4 in end mill'; })()",
    )
    .await
    .expect("edited");
    click(&page, r#"#tools tr[data-tool="1"] .tool-save"#).await;
    let file = || std::fs::read_to_string(&table).expect("the table");
    until(&page, Duration::from_secs(10), "T1 written", async |_| {
        file().starts_with("T1 P1 Z+1.500000 D6.350000 ;1/4 in end mill\n")
    })
    .await;
    // A wrong value: refused with why, the file as it was.
    page.evaluate("document.querySelector('#tools tr[data-tool=\"2\"] .diameter').value = '-3'")
        .await
        .expect("edited");
    click(&page, r#"#tools tr[data-tool="2"] .tool-save"#).await;
    until(&page, Duration::from_secs(10), "the refusal shown", async |p| {
        text(p, "document.getElementById('access').textContent").await == "the diameter must be 0 … 1000 mm, got -3"
    })
    .await;
    assert!(file().contains("T2 P2 D3.000000 ;3 mm drill"), "{}", file());
    // Tool 7 added, tool 2 removed: the rows follow the file.
    page.evaluate("document.getElementById('tool-new').value = '7'")
        .await
        .expect("typed");
    click(&page, "#tool-add").await;
    until(&page, Duration::from_secs(10), "tool 7 added", async |p| {
        text(p, rows).await == "3"
    })
    .await;
    click(&page, r#"#tools tr[data-tool="2"] .tool-remove"#).await;
    until(&page, Duration::from_secs(10), "tool 2 removed", async |p| {
        text(p, rows).await == "2"
    })
    .await;
    assert_eq!(file(), "T1 P1 Z+1.500000 D6.350000 ;1/4 in end mill\nT7 P7\n");
    if let Some(shots) = std::env::var_os("PKM_SCREENSHOTS") {
        let shots = std::path::PathBuf::from(shots);
        page.evaluate("document.getElementById('tools-box').scrollIntoView()")
            .await
            .expect("scrolled");
        page.screenshot(&shots.join("hmi-tools.png"))
            .await
            .expect("a screenshot");
    }
    // A job made now plans with the table as changed: G43 H1 takes its Z offset of 1.5 mm.
    page.evaluate("document.getElementById('mdi-text').value = 'G43 H1\\nG0 Z0'")
        .await
        .expect("typed");
    click(&page, "#nc-mdi").await;
    until(&page, Duration::from_secs(20), "the tool at z 1.5", async |p| {
        state(p).await == "READY" && (shown(p, "z").await - 1.5).abs() < 0.005
    })
    .await;
    plc.stop();
    assert!(
        plc.log()
            .contains("tool table: tool 1: T1 P1 Z+1.500000 D6.350000 ;1/4 in end mill"),
        "{}",
        plc.log()
    );
    // The trace carries the table the MDI was planned with: it replays identically.
    common::assert_replays_identically(&trace, &["--config", config.to_str().expect("utf-8")]);
}
