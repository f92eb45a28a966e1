//! A WebSocket client of the operator's screen, for the tests that drive a running PLC through
//! it: its messages as JSON, the replies to commands, waiting for a state, sending a command.

use std::time::{Duration, Instant};

use futures::{SinkExt, StreamExt};
use tokio_tungstenite::tungstenite::Message;

use crate::common;

/// A WebSocket client of the screen.
pub type Ws = tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// The screen's next message as JSON; panics after `within`.
pub async fn next(ws: &mut Ws, within: Duration) -> serde_json::Value {
    next_within(ws, within)
        .await
        .unwrap_or_else(|| panic!("no message from the screen within {within:?}"))
}

/// The screen's next message as JSON, `None` when none comes within `within`.
pub async fn next_within(ws: &mut Ws, within: Duration) -> Option<serde_json::Value> {
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
pub async fn reply(ws: &mut Ws, within: Duration) -> serde_json::Value {
    let start = Instant::now();
    loop {
        let m = next(ws, within.saturating_sub(start.elapsed())).await;
        if !matches!(m["type"].as_str(), Some("frame" | "alarm" | "origins")) {
            return m;
        }
    }
}

/// Waits for a frame in `state`; the frame (its simulated time `t_s` included).
pub async fn until_state(ws: &mut Ws, state: &str, within: Duration) -> serde_json::Value {
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
                return m;
            }
            last = m;
        }
    }
}

/// Sends `command` (JSON) to the screen.
pub async fn send(ws: &mut Ws, command: serde_json::Value) {
    ws.send(Message::Text(command.to_string().into()))
        .await
        .expect("the command is sent");
}

/// Starts the run `command` (with `--hmi`) and connects to its screen: the run, and the
/// WebSocket once the screen said hello.
pub async fn start_with_screen(command: std::process::Command) -> (common::Logged, Ws) {
    let (plc, url) = common::Logged::start(command, "operator screen at ", Duration::from_secs(30));
    let ws_url = url.replacen("http://", "ws://", 1) + "ws";
    let (mut ws, _) = tokio_tungstenite::connect_async(ws_url.as_str())
        .await
        .expect("connects");
    assert_eq!(next(&mut ws, Duration::from_secs(10)).await["type"], "hello");
    (plc, ws)
}
