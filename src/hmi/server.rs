//! The web server of the operator's screen (axum on the runtime's tokio runtime, off the cyclic
//! path): the page and its assets built into the binary, and one WebSocket per client that
//! pushes every published frame (at the main cycle's rate) and takes the client's commands.
//!
//! Commands need the token when one is configured (`?token=` on the WebSocket's URL); without
//! it a client only watches. Every command is logged with the client's address. The jog is a
//! dead-man: a release, a closed connection or a client that stops refreshing it for
//! [`JOG_TIMEOUT`] sets it to 0.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use axum::Router;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{ConnectInfo, Query, State};
use axum::http::header;
use axum::response::{Html, IntoResponse, Response};
use axum::routing::get;
use serde::Deserialize;
use serde_json::{Value as Json, json};
use tokio::sync::broadcast;
use tracing::{info, warn};

use pkm_api::hmi::JOG_AXIS_RANGE;

use super::commands::{CommandSink, press};
use super::frame::{Frame, FrameReader};
use crate::image::Value;

/// A jog not refreshed for this long stops (the page refreshes it every 20 ms while held).
pub const JOG_TIMEOUT: Duration = Duration::from_millis(60);
/// How often the server looks for a newly published frame.
const FRAME_POLL: Duration = Duration::from_millis(2);

const INDEX_HTML: &str = include_str!("page/index.html");
const APP_JS: &str = include_str!("page/app.js");
const APP_CSS: &str = include_str!("page/app.css");

/// What the server shares with every connection.
pub struct Shared {
    /// The first message to every client: the machine, the configuration, the variables.
    hello: Json,
    frames: broadcast::Sender<Arc<str>>,
    sink: CommandSink,
    token: Option<String>,
    next_client: AtomicU64,
    /// The client that jogs (its id), with when it last refreshed the jog.
    jog_owner: std::sync::Mutex<Option<(u64, Instant)>>,
    /// A program runs (the last frame's state is AUTO): no other is loaded.
    running: std::sync::atomic::AtomicBool,
    /// How many programs the run has.
    programs: usize,
}

/// What the screen is told once, at connection: the machine and its variables.
pub struct HmiInfo {
    /// The machine's name (or `runtime` without one).
    pub machine: String,
    /// The configuration's file.
    pub config: String,
    /// Every variable of the process image, in the image's order, with its type.
    pub variables: Vec<(String, String)>,
    /// The run's NC programs, numbered from 1 (`NC_PROGRAM` holds the loaded one's number).
    pub programs: Vec<ScreenProgram>,
    /// The programs offered that cannot run on the machine: file and why.
    pub refused: Vec<(String, String)>,
    /// The machine's pose coordinates (`x`, `y`, … ): a jog button each.
    pub axes: Vec<String>,
    /// The variables of the machine's measured joint positions: a jog button each (world mode).
    pub joints: Vec<String>,
    /// The drawing of the mechanism, if its kinematics draws one.
    pub mechanism: Option<super::mechanism::Mechanism>,
}

/// An NC program as the screen shows it.
pub struct ScreenProgram {
    /// Its file.
    pub file: String,
    /// Its text.
    pub text: String,
    /// The programmed tool path (x y z of the commanded pose along the program's time line),
    /// for the page's preview.
    pub path: Vec<[f64; 3]>,
}

/// Builds the router and the task that pushes frames; `token`: commands need it.
pub fn router(info: HmiInfo, mut frames: FrameReader, sink: CommandSink, token: Option<String>) -> Router {
    let hello = json!({
        "type": "hello",
        "machine": info.machine,
        "config": info.config,
        "variables": info.variables.iter().map(|(n, t)| json!([n, t])).collect::<Vec<_>>(),
        "programs": info.programs.iter().map(|p| json!({"file": p.file, "text": p.text, "path": p.path})).collect::<Vec<_>>(),
        "refused": info.refused.iter().map(|(file, why)| json!({"file": file, "why": why})).collect::<Vec<_>>(),
        "axes": info.axes,
        "joints": info.joints,
    });
    let (tx, _) = broadcast::channel::<Arc<str>>(16);
    let shared = Arc::new(Shared {
        hello,
        frames: tx.clone(),
        sink,
        token,
        next_client: AtomicU64::new(1),
        jog_owner: std::sync::Mutex::new(None),
        running: std::sync::atomic::AtomicBool::new(false),
        programs: info.programs.len(),
    });
    let pump = Arc::clone(&shared);
    let mut mechanism = info.mechanism;
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(FRAME_POLL);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        loop {
            tick.tick().await;
            // Taken even with nobody listening, so that a client gets the newest next; written
            // out only for listeners.
            let newer = frames.newer();
            if let Some(frame) = &newer {
                pump.running.store(frame.status.state == "AUTO", Ordering::Relaxed);
            }
            if let Some(frame) = newer
                && tx.receiver_count() > 0
            {
                // The links only where the positions are the kinematics' (once referenced).
                let operating = matches!(frame.status.state.as_str(), "READY" | "MOTION" | "AUTO");
                let links = mechanism
                    .as_mut()
                    .filter(|_| operating)
                    .and_then(|m| m.links(&frame.image));
                let _ = tx.send(Arc::from(frame_json(frame, links).as_str()));
            }
            pump.release_stale_jog();
        }
    });
    Router::new()
        .route("/", get(|| async { Html(INDEX_HTML) }))
        .route(
            "/app.js",
            get(|| async { asset("text/javascript; charset=utf-8", APP_JS) }),
        )
        .route("/app.css", get(|| async { asset("text/css; charset=utf-8", APP_CSS) }))
        .route("/ws", get(socket))
        .with_state(shared)
}

fn asset(content_type: &'static str, body: &'static str) -> Response {
    ([(header::CONTENT_TYPE, content_type)], body).into_response()
}

/// A frame as the page reads it.
fn frame_json(f: &Frame, links: Option<&[[[f64; 3]; 2]]>) -> String {
    let s = &f.status;
    let value = |v: &Value| match *v {
        Value::Bool(b) => json!(b),
        Value::Int(i) => json!(i),
        Value::Uint(u) => json!(u),
        Value::Dint(d) => json!(d),
        Value::Real(x) => serde_json::Number::from_f64(x).map_or(Json::Null, Json::Number),
    };
    json!({
        "type": "frame",
        "seq": f.seq,
        "t_s": s.t_ns as f64 * 1e-9,
        "state": s.state,
        "reason": s.reason,
        "note": s.note,
        "values": s.values.iter().map(|(n, v)| json!([n, serde_json::Number::from_f64(*v).map_or(Json::Null, Json::Number)])).collect::<Vec<_>>(),
        "classes": s.classes.iter().map(|c| json!({
            "name": c.name, "cycles": c.cycles, "overruns": c.overruns, "violations": c.violations,
            "late_mean_us": c.lateness_mean_ns / 1e3, "late_max_us": c.lateness_max_ns as f64 / 1e3,
            "exec_mean_us": c.exec_mean_ns / 1e3, "exec_max_us": c.exec_max_ns as f64 / 1e3,
        })).collect::<Vec<_>>(),
        "bus_fault": f.bus_fault,
        "published_unix_us": f.published_unix_us,
        "links": links.map(|l| l.iter().map(|[a, b]| json!([a, b])).collect::<Vec<_>>()),
        "image": f.image.iter().map(value).collect::<Vec<_>>(),
    })
    .to_string()
}

/// The WebSocket's query: the token, if the client has one.
#[derive(Deserialize)]
struct Access {
    token: Option<String>,
}

async fn socket(
    ws: WebSocketUpgrade,
    Query(access): Query<Access>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    State(shared): State<Arc<Shared>>,
) -> Response {
    let commands = match &shared.token {
        None => true,
        Some(t) => access.token.as_deref() == Some(t.as_str()),
    };
    ws.on_upgrade(move |socket| client(socket, peer, commands, shared))
}

/// A command from the page.
#[derive(Deserialize)]
#[serde(tag = "cmd", rename_all = "snake_case", deny_unknown_fields)]
enum Command {
    /// STOP (and, in ERROR, its acknowledgement).
    Stop,
    /// The axis button.
    Axes,
    /// The jog's deflection (0, 0: released), on the stick's pair of axes (`axis` 0 or left out),
    /// on the `axis`-th pose coordinate alone, or (`axis` −k) on the k-th joint alone.
    Jog {
        x: f64,
        y: f64,
        #[serde(default)]
        axis: i16,
    },
    /// Program start, hold or resume.
    Program { what: String },
    /// Load the run's program of this number (from 1) in place of the loaded one.
    Load { program: i16 },
}

async fn client(mut socket: WebSocket, peer: SocketAddr, commands: bool, shared: Arc<Shared>) {
    let id = shared.next_client.fetch_add(1, Ordering::Relaxed);
    let mut frames = shared.frames.subscribe();
    info!(
        "screen {peer}: connected ({})",
        if commands {
            "may command"
        } else {
            "watching only: no token"
        }
    );
    let mut hello = shared.hello.clone();
    hello["commands"] = json!(commands);
    if socket.send(Message::Text(hello.to_string().into())).await.is_err() {
        return;
    }
    loop {
        tokio::select! {
            frame = frames.recv() => match frame {
                Ok(text) => {
                    if socket.send(Message::Text(text.as_ref().into())).await.is_err() {
                        break;
                    }
                }
                // A slow client skips frames; it gets the newest next.
                Err(broadcast::error::RecvError::Lagged(_)) => {}
                Err(broadcast::error::RecvError::Closed) => break,
            },
            message = socket.recv() => match message {
                Some(Ok(Message::Text(text))) => {
                    if !commands {
                        let _ = socket
                            .send(Message::Text(r#"{"type":"refused","why":"watching only: commands need the token"}"#.into()))
                            .await;
                        continue;
                    }
                    match serde_json::from_str::<Command>(&text) {
                        Ok(c) => {
                            if let Err(why) = shared.apply(id, peer, c) {
                                let refusal = json!({"type": "refused", "why": why}).to_string();
                                let _ = socket.send(Message::Text(refusal.into())).await;
                            }
                        }
                        Err(e) => warn!("screen {peer}: a command that is not one ({e}): {}", crate::config::shorten(&text)),
                    }
                }
                Some(Ok(Message::Close(_))) | None | Some(Err(_)) => break,
                Some(Ok(_)) => {}
            },
        }
    }
    shared.release_jog(id, peer, "connection closed");
    info!("screen {peer}: disconnected");
}

impl Shared {
    /// Carries out a client's command; a refused one says why.
    fn apply(&self, id: u64, peer: SocketAddr, command: Command) -> Result<(), String> {
        match command {
            Command::Load { program } => {
                let known = usize::try_from(program).is_ok_and(|k| (1..=self.programs).contains(&k));
                if !known {
                    warn!("screen {peer}: no program {program} to load");
                    return Err(format!("no program {program}: the run has {}", self.programs));
                }
                if self.running.load(Ordering::Relaxed) {
                    info!("screen {peer}: load program {program} refused: a program runs");
                    return Err("a program runs: another is loaded once it has ended or stopped".into());
                }
                info!("screen {peer}: load program {program}");
                self.sink.update(|c| c.program = program);
            }
            Command::Stop => {
                info!("screen {peer}: STOP");
                self.sink.update(|c| c.presses[press::STOP] += 1);
            }
            Command::Axes => {
                info!("screen {peer}: axis button");
                self.sink.update(|c| c.presses[press::AXES] += 1);
            }
            Command::Program { what } => {
                let k = match what.as_str() {
                    "start" => 0,
                    "hold" => 1,
                    "resume" => 2,
                    other => {
                        warn!(
                            "screen {peer}: no program command \"{}\"",
                            crate::config::shorten(other)
                        );
                        return Err(format!("no program command \"{}\"", crate::config::shorten(other)));
                    }
                };
                info!("screen {peer}: program {what}");
                self.sink.update(|c| c.presses[press::NC[k]] += 1);
            }
            Command::Jog { x, y, axis } => {
                let (x, y) = (finite(x).clamp(-1.0, 1.0), finite(y).clamp(-1.0, 1.0));
                let mut owner = self.jog_owner.lock().unwrap_or_else(|p| p.into_inner());
                if x == 0.0 && y == 0.0 {
                    if owner.is_some_and(|(o, _)| o == id) {
                        *owner = None;
                        info!("screen {peer}: jog released");
                        self.sink.update(|c| c.jog = [0.0; 2]);
                    }
                    return Ok(());
                }
                if owner.is_none_or(|(o, _)| o != id) {
                    info!("screen {peer}: jog {x:.2} {y:.2} (axis {axis})");
                }
                *owner = Some((id, Instant::now()));
                self.sink.update(|c| {
                    c.jog = [x, y];
                    c.jog_axis = axis.clamp(*JOG_AXIS_RANGE.start(), *JOG_AXIS_RANGE.end());
                });
            }
        }
        Ok(())
    }

    /// Stops the jog if client `id` holds it.
    fn release_jog(&self, id: u64, peer: SocketAddr, why: &str) {
        let mut owner = self.jog_owner.lock().unwrap_or_else(|p| p.into_inner());
        if owner.is_some_and(|(o, _)| o == id) {
            *owner = None;
            info!("screen {peer}: jog stopped: {why}");
            self.sink.update(|c| c.jog = [0.0; 2]);
        }
    }

    /// Stops a jog that its client stopped refreshing.
    fn release_stale_jog(&self) {
        let mut owner = self.jog_owner.lock().unwrap_or_else(|p| p.into_inner());
        if owner.is_some_and(|(_, at)| at.elapsed() > JOG_TIMEOUT) {
            *owner = None;
            warn!(
                "screen: the jog was not refreshed for {} ms: stopped",
                JOG_TIMEOUT.as_millis()
            );
            self.sink.update(|c| c.jog = [0.0; 2]);
        }
    }
}

fn finite(v: f64) -> f64 {
    if v.is_finite() { v } else { 0.0 }
}
