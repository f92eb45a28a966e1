//! The web server of the operator's screen (axum on the runtime's tokio runtime, off the cyclic
//! path): the page and its assets built into the binary, and one WebSocket per client that
//! pushes every published frame (at the main cycle's rate) and takes the client's commands.
//!
//! Who is served and who commands is [`super::access`]'s: the Host of every request, the Origin
//! of every WebSocket, the token. Bounded: connections ([`super::listener`]),
//! WebSocket clients ([`ServerOptions::max_clients`]), messages from a client (4 KiB) and
//! commands per second per client ([`COMMANDS_PER_S`]); what is sent at connection (the hello)
//! does not grow with the programs' length — their text is fetched a window at a time
//! ([`TEXT_WINDOW`] lines). Every command is logged with the client's address; a refused one is
//! logged once per client, and counted. The jog is a dead-man: a release, a closed connection or
//! a client that stops refreshing it for [`JOG_TIMEOUT`] sets it to 0.

use std::net::{IpAddr, SocketAddr};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use axum::Router;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{ConnectInfo, Query, Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::get;
use serde::Deserialize;
use serde_json::{Value as Json, json};
use tokio::sync::broadcast;
use tracing::{info, warn};

use pkm_api::hmi::JOG_AXIS_RANGE;

use super::access::{Access, Credentials, header_text};
use super::commands::{CommandSink, FEED_OVERRIDE_RANGE, RAPID_OVERRIDE_RANGE, SPINDLE_OVERRIDE_RANGE, press};
use super::cut::CutPath;
use super::jobs::JobDesk;
use super::listener::Peer;
pub use super::served::{ScreenProgram, TEXT_WINDOW, preview};
use super::served::{Served, frame_json};

mod job_commands;
use crate::runtime::backoff::Backoff;
use crate::runtime::frame::FrameFeed;
use crate::runtime::log_limit::Limited;

/// A jog not refreshed for this long stops (the page refreshes it every 20 ms while held).
pub const JOG_TIMEOUT: Duration = Duration::from_millis(60);
/// How often, between frames, the server looks for a jog whose client went quiet.
const STALE_JOG_POLL: Duration = Duration::from_millis(5);
/// The longest message a client may send (its commands are a few dozen bytes).
pub const MAX_CLIENT_MESSAGE: usize = 4096;
/// Commands (and text requests) a client may send per second, on average; as many at once. The
/// page sends 50 a second while a jog is held. STOP and a jog's release are never dropped.
pub const COMMANDS_PER_S: f64 = 100.0;
/// How often a client may ask for the cut path (it is up to about 100 kB).
pub const CUT_EVERY: Duration = Duration::from_secs(1);
/// How many of the tool's recent points every frame carries (a client may take one frame in
/// twenty).
const TRAIL: usize = 20;
/// The longest incremental jog (mm, or degrees) a step from the screen makes.
pub const MAX_STEP_MM: f64 = 10.0;
/// The most programs refused by `--programs` that the hello lists (the rest are counted).
const MAX_REFUSED_LISTED: usize = 50;

const INDEX_HTML: &str = include_str!("../page/index.html");
const APP_JS: &str = include_str!("../page/app.js");
const APP_CSS: &str = include_str!("../page/app.css");

/// How the screen is served: who may reach it and how many.
#[derive(Clone, Debug)]
pub struct ServerOptions {
    /// Host, Origin and token rules.
    pub access: Access,
    /// WebSocket clients at once.
    pub max_clients: usize,
}

/// What the server shares with every connection.
pub struct Shared {
    /// The first message to every client: the machine, the configuration, the variables.
    hello: Json,
    frames: broadcast::Sender<Arc<str>>,
    sink: CommandSink,
    options: ServerOptions,
    next_client: AtomicU64,
    /// WebSocket clients connected now.
    clients: AtomicUsize,
    /// The client that jogs (its id), with when it last refreshed the jog.
    jog_owner: std::sync::Mutex<Option<(u64, Instant)>>,
    /// A program runs (the last frame's state is AUTO): no other is loaded.
    running: AtomicBool,
    /// The machine is in ERROR (the last frame's state): there is an error to acknowledge.
    in_error: AtomicBool,
    /// The machine is READY (the last frame's state): it may reference again.
    ready: AtomicBool,
    /// A manual tool change waits for its confirmation (the last frame's `TOOL_CHANGE`).
    tool_change: AtomicBool,
    /// The change that waits or came last, as the last frame has it: (its
    /// `TOOL_CHANGE_NUMBER`, the tool `TOOL_PREP_NUMBER` asks for), packed in one word so that
    /// a confirmation is checked against one frame's pair.
    tool_asked: AtomicI64,
    /// The machine's pose coordinates (`x`, `y`, …), which a touch-off names.
    axes: Vec<String>,
    /// The alarm and message history.
    alarms: super::alarms::Alarms,
    /// The run's programs: text and path, served on request.
    programs: Vec<Served>,
    /// Where jobs are made.
    jobs: Option<JobDesk>,
    /// WebSocket clients that watch only (no token), of `clients`.
    watchers: AtomicUsize,
    /// Wrong tokens per source address: each answered later than the one before.
    guesses: Backoff<IpAddr>,
    /// One line per source and interval about wrong tokens, and about watchers coming and going.
    guess_log: Limited,
    watch_log: Limited,
    /// The backplot's cut path, if the run has programs.
    cut: Option<std::sync::Mutex<CutPath>>,
    /// The step of the jog under way, with the program it replaced.
    step_return: std::sync::Mutex<Option<job_commands::StepReturn>>,
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
    /// Where the screen makes jobs (MDI, a program from a line), if the run has a library.
    pub jobs: Option<JobDesk>,
    /// The tool table's tools: number and comment (the manual tool change names them).
    pub tools: Vec<(u32, String)>,
    /// The run's programs, whose messages (MSG) the screen shows as the run reaches them.
    pub library: Option<pkm_api::library::NcLibrary>,
    /// A simulation paced at this many times real time (`run --virtual --pace`): the screen
    /// says so; `None`: the machine itself.
    pub simulation: Option<f64>,
}

/// The run's tool table as the screen shows it: its file, whether edits are written to it, and
/// its tools (number, pocket, offsets x y z a b c, diameter, comment).
fn tool_table_json(keeper: &crate::runtime::tool_table::ToolTableKeeper) -> Json {
    let tools: Vec<Json> = keeper
        .table()
        .tools
        .iter()
        .map(|t| json!({"number": t.number, "pocket": t.pocket, "offsets": t.offsets, "diameter": t.diameter, "comment": t.comment}))
        .collect();
    json!({"file": keeper.file(), "writes": keeper.writes(), "tools": tools})
}

/// Sends every page the tool table each time a change is kept (an edit on the screen, a
/// program's `G10 L1` written back), as `{"type": "tools", …}`.
pub(super) fn tool_table_news(
    keeper: Arc<crate::runtime::tool_table::ToolTableKeeper>,
    pages: broadcast::Sender<Arc<str>>,
) {
    let mut changes = keeper.changes();
    tokio::spawn(async move {
        while changes.changed().await.is_ok() {
            if pages.receiver_count() > 0 {
                let mut news = tool_table_json(&keeper);
                news["type"] = json!("tools");
                let _ = pages.send(Arc::from(news.to_string().as_str()));
            }
        }
    });
}

/// Builds the router and the task that pushes frames.
pub fn router(info: HmiInfo, mut frames: FrameFeed, sink: CommandSink, options: ServerOptions) -> Router {
    let programs: Vec<Served> = info.programs.into_iter().map(Served::new).collect();
    let hello = json!({
        "type": "hello",
        "machine": info.machine,
        "config": info.config,
        "variables": info.variables.iter().map(|(n, t)| json!([n, t])).collect::<Vec<_>>(),
        "programs": programs.iter().map(|p| json!({"file": p.program.file, "lines": p.total, "planned_s": p.program.planned_s})).collect::<Vec<_>>(),
        "refused": info.refused.iter().take(MAX_REFUSED_LISTED).map(|(file, why)| json!({"file": file, "why": crate::runtime::config::shorten(why)})).collect::<Vec<_>>(),
        "refused_more": info.refused.len().saturating_sub(MAX_REFUSED_LISTED),
        "axes": info.axes,
        "joints": info.joints,
        "jobs": info.jobs.is_some(),
        "simulation": info.simulation,
        "tools": info.tools.iter().map(|(n, comment)| json!([n, comment])).collect::<Vec<_>>(),
        // Where the kinematics draws the mechanism, its links in the middle of the joints'
        // ranges: the page lays the drawing's box out by them from the start, so that nothing
        // moves when the first pose comes (once referenced).
        "mechanism_sample": info.mechanism.as_ref().map(|m| m.sample()),
    });
    let at = |var: &str| info.variables.iter().position(|(n, _)| n == var);
    let tool_change_at = at(pkm_api::trajectory::vars::TOOL_CHANGE.name());
    let tool_asked_at = (
        at(pkm_api::trajectory::vars::TOOL_CHANGE_NUMBER.name()),
        at(pkm_api::trajectory::vars::TOOL_PREP_NUMBER.name()),
    );
    let mut messages = crate::runtime::messages::MessageWatch::of_names(&info.variables, info.library.as_ref());
    let (tx, _) = broadcast::channel::<Arc<str>>(16);
    let shared = Arc::new(Shared {
        hello,
        frames: tx.clone(),
        sink,
        options,
        next_client: AtomicU64::new(1),
        clients: AtomicUsize::new(0),
        jog_owner: std::sync::Mutex::new(None),
        running: AtomicBool::new(false),
        in_error: AtomicBool::new(false),
        ready: AtomicBool::new(false),
        tool_change: AtomicBool::new(false),
        tool_asked: AtomicI64::new(0),
        axes: info.axes.clone(),
        alarms: super::alarms::Alarms::default(),
        programs,
        jobs: info.jobs,
        watchers: AtomicUsize::new(0),
        guesses: Backoff::default(),
        guess_log: Limited::new("screen: wrong tokens"),
        watch_log: Limited::new("screen: watchers connected or disconnected"),
        cut: CutPath::of(&info.variables).map(std::sync::Mutex::new),
        step_return: std::sync::Mutex::new(None),
    });
    if let Some(keeper) = shared.jobs.as_ref().and_then(|d| d.tools()) {
        tool_table_news(Arc::clone(keeper), tx.clone());
    }
    let pump = Arc::clone(&shared);
    let mut mechanism = info.mechanism;
    let mut last_message: Option<Json> = None;
    // The measured tool point of the last frames while a program runs (frame number, x y z):
    // every frame carries them, so a client that takes one frame in five misses no point.
    let mut trail: std::collections::VecDeque<[f64; 4]> = std::collections::VecDeque::with_capacity(TRAIL + 1);
    let at = |name: &str| info.variables.iter().position(|(n, _)| n == name);
    let tool_at = [
        at(pkm_api::trajectory::vars::NC_TOOL[0].name()),
        at(pkm_api::trajectory::vars::NC_TOOL[1].name()),
        at(pkm_api::trajectory::vars::NC_TOOL[2].name()),
    ];
    let nc_state_at = at(pkm_api::trajectory::vars::NC_STATE.name());
    tokio::spawn(async move {
        // A held jog whose client went quiet is looked at between frames too — only while a
        // jog is held: ticking all the time woke the process 200 times a second for nothing.
        let mut tick = tokio::time::interval(STALE_JOG_POLL);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        loop {
            let jogging = pump.jog_held();
            let newer = tokio::select! {
                frame = frames.next() => match frame {
                    Some(frame) => Some(frame),
                    None => break,
                },
                _ = tick.tick(), if jogging => None,
            };
            // Taken even with nobody listening, so that a client gets the newest next; written
            // out only for listeners.
            if let Some(frame) = &newer {
                pump.running.store(frame.status.state == "AUTO", Ordering::Relaxed);
                pump.in_error.store(frame.status.state == "ERROR", Ordering::Relaxed);
                pump.ready.store(frame.status.state == "READY", Ordering::Relaxed);
                let waits = tool_change_at.and_then(|i| frame.image.get(i)) == Some(&crate::image::Value::Bool(true));
                pump.tool_change.store(waits, Ordering::Relaxed);
                let word = |at: Option<usize>| match at.and_then(|i| frame.image.get(i)) {
                    Some(crate::image::Value::Dint(v)) => *v,
                    _ => 0,
                };
                let (change, tool) = (word(tool_asked_at.0), word(tool_asked_at.1));
                pump.tool_asked.store(pack(change, tool), Ordering::Relaxed);
                // The newest message (MSG) the run reached, with when: the page shows it, the
                // history keeps it.
                let mut reached = None;
                if let Some(watch) = &mut messages {
                    let t_s = frame.status.t_ns as f64 * 1e-9;
                    let (new, _) = watch.take(&frame.image);
                    if let Some(m) = new
                        .iter()
                        .rev()
                        .find(|m| m.kind == pkm_api::trajectory::NcMessageKind::Msg)
                    {
                        let text = crate::runtime::messages::shown(&m.text);
                        last_message = Some(json!([t_s, m.line, text]));
                        reached = Some((m.line, text));
                    }
                }
                let real = |i: Option<usize>| match i.and_then(|i| frame.image.get(i)) {
                    Some(crate::image::Value::Real(v)) => *v,
                    _ => 0.0,
                };
                let running = matches!(
                    nc_state_at.and_then(|i| frame.image.get(i)),
                    Some(crate::image::Value::Int(1 | 2 | 3 | 4 | 6 | 7 | 8))
                );
                if running && tool_at[0].is_some() {
                    if trail.len() == TRAIL {
                        trail.pop_front();
                    }
                    trail.push_back([frame.seq as f64, real(tool_at[0]), real(tool_at[1]), real(tool_at[2])]);
                }
                let message = reached.as_ref().map(|(l, t)| (*l, t.as_str()));
                for entry in pump.alarms.observe(frame, message) {
                    if tx.receiver_count() > 0 {
                        let _ = tx.send(Arc::from(entry.to_string().as_str()));
                    }
                }
                if let Some(desk) = &pump.jobs {
                    // A replaced job's plan is freed on a thread of its own, not waited for.
                    drop(desk.observe(&frame.status.state, &frame.image));
                    pump.step_watch(&frame.status.state);
                }
                if let Some(cut) = &pump.cut {
                    cut.lock().unwrap_or_else(|p| p.into_inner()).observe(&frame.image);
                }
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
                let _ = tx.send(Arc::from(
                    frame_json(&frame, links, last_message.as_ref(), &trail).as_str(),
                ));
            }
            pump.release_stale_jog();
        }
    });
    Router::new()
        .route("/", get(index))
        .route(
            "/app.js",
            get(|| async { asset("text/javascript; charset=utf-8", APP_JS) }),
        )
        .route("/app.css", get(|| async { asset("text/css; charset=utf-8", APP_CSS) }))
        .route("/ws", get(socket))
        .layer(middleware::from_fn_with_state(Arc::clone(&shared), guard))
        .with_state(shared)
}

/// Every request: its Host must be one the screen answers to (no DNS rebinding), and every
/// response says it must not be framed by another page (no clickjacking).
async fn guard(State(shared): State<Arc<Shared>>, request: Request, next: Next) -> Response {
    let mut response = if shared.options.access.host_allowed(request.headers()) {
        next.run(request).await
    } else {
        let host = header_text(request.headers(), header::HOST)
            .map(crate::runtime::config::shorten)
            .unwrap_or_default();
        warn!(
            "screen: refused a request for Host \"{host}\" (not an IP address, localhost or an allowed origin's host)"
        );
        (
            StatusCode::FORBIDDEN,
            "this screen answers to its IP address or localhost; allow another name with --hmi-allow-origin\n",
        )
            .into_response()
    };
    let headers = response.headers_mut();
    headers.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    headers.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static("frame-ancestors 'none'"),
    );
    headers.insert(header::X_CONTENT_TYPE_OPTIONS, HeaderValue::from_static("nosniff"));
    headers.insert(header::REFERRER_POLICY, HeaderValue::from_static("no-referrer"));
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    response
}

/// The page; opened with the right `?token=`, it also sets the token's cookie, so that its
/// WebSocket carries the token without it in the address.
async fn index(
    Query(given): Query<TokenQuery>,
    ConnectInfo(peer): ConnectInfo<Peer>,
    State(shared): State<Arc<Shared>>,
) -> Response {
    // A wrong token in the page's address is a guess like a wrong token on the WebSocket.
    if given.token.is_some() && shared.options.access.token_cookie(given.token.as_deref()).is_none() {
        shared.guessed(peer.0).await;
    }
    let mut response = Html(INDEX_HTML).into_response();
    if let Some(cookie) = shared.options.access.token_cookie(given.token.as_deref())
        && let Ok(value) = HeaderValue::from_str(&cookie)
    {
        response.headers_mut().insert(header::SET_COOKIE, value);
    }
    response
}

fn asset(content_type: &'static str, body: &'static str) -> Response {
    ([(header::CONTENT_TYPE, content_type)], body).into_response()
}

/// The query of the page's and the WebSocket's address: the token, if the client has one.
#[derive(Deserialize)]
struct TokenQuery {
    token: Option<String>,
}

async fn socket(
    ws: WebSocketUpgrade,
    Query(given): Query<TokenQuery>,
    headers: HeaderMap,
    ConnectInfo(peer): ConnectInfo<Peer>,
    State(shared): State<Arc<Shared>>,
) -> Response {
    let access = &shared.options.access;
    if !access.origin_allowed(&headers) {
        let origin = header_text(&headers, header::ORIGIN)
            .map(crate::runtime::config::shorten)
            .unwrap_or_default();
        warn!(
            "screen {peer}: WebSocket refused: a page of another origin ({origin}); allow it with --hmi-allow-origin"
        );
        return (StatusCode::FORBIDDEN, "a page of another origin may not connect\n").into_response();
    }
    let credentials = access.credentials(given.token.as_deref(), &headers);
    match credentials {
        Credentials::Wrong => shared.guessed(peer.0).await,
        Credentials::Command => shared.guesses.accepted(&peer.0.ip()),
        Credentials::Watch => {}
    }
    let commands = credentials == Credentials::Command;
    // Counted here, released when the client's task ends. Watchers have fewer places than
    // clients who may command: the operator with the token always finds one.
    let Some(place) = shared.take_place(commands) else {
        let (what, max) = if commands {
            ("clients", shared.options.max_clients)
        } else {
            ("watching clients", shared.watch_max())
        };
        shared.watch_log.warn(peer.0.ip(), || {
            format!("screen {peer}: WebSocket refused: already {max} {what} (--hmi-max-clients)")
        });
        return (StatusCode::SERVICE_UNAVAILABLE, "too many clients\n").into_response();
    };
    ws.max_message_size(MAX_CLIENT_MESSAGE)
        .max_frame_size(MAX_CLIENT_MESSAGE)
        .on_upgrade(move |socket| async move {
            client(socket, peer.0, commands, &shared).await;
            drop(place);
        })
}

/// A WebSocket client's place among the clients (and the watchers), given back when dropped.
struct Place {
    shared: Arc<Shared>,
    watcher: bool,
}

impl Drop for Place {
    fn drop(&mut self) {
        self.shared.clients.fetch_sub(1, Ordering::AcqRel);
        if self.watcher {
            self.shared.watchers.fetch_sub(1, Ordering::AcqRel);
        }
    }
}

/// A message from the page: a command, or a request for part of a program's text.
#[derive(Deserialize)]
#[serde(tag = "cmd", rename_all = "snake_case", deny_unknown_fields)]
enum Command {
    /// STOP (and, in ERROR, its acknowledgement, as on the panel).
    Stop {},
    /// The acknowledgement of an error: a STOP press once STOP has been released for the
    /// programs' lockout, so one sent right after the STOP is not lost; refused outside ERROR
    /// (where a STOP press would stop the machine).
    Acknowledge {},
    /// The axis button.
    Axes {},
    /// Reference the machine again: from READY only (refused elsewhere, with why).
    Reference {},
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
    /// The feed, rapid or spindle override, or several (percent).
    Override {
        #[serde(default)]
        feed: Option<i16>,
        #[serde(default)]
        rapid: Option<i16>,
        #[serde(default)]
        spindle: Option<i16>,
    },
    /// Single block on or off.
    SingleBlock { on: bool },
    /// The tool the manual tool change asks for is in the spindle: the program goes on. It
    /// names the tool and the change (`TOOL_CHANGE_NUMBER`) it confirms: one that does not
    /// match the change that waits is refused (a late second click confirmed the next change).
    ToolChanged { tool: i32, change: i32 },
    /// An incremental jog: axis `axis` moved by `mm` (at most [`MAX_STEP_MM`] either way) at
    /// rapid speed, as the MDI line `G91 G0 X…` (planned, checked, traced as one); from READY.
    Step { axis: String, mm: f64 },
    /// Touch-off: work coordinate system `system` (1: G54 … 6: G59; G54 when left out) moved in
    /// `axis` so that where the tool stands reads `value`, as G10 L20 would; from READY.
    TouchOff {
        axis: String,
        value: f64,
        #[serde(default)]
        system: Option<u8>,
    },
    /// Lines `from` … of program `program`'s text (a read: watchers may ask too).
    Text { program: usize, from: usize },
    /// The programmed path of program `program` (a read).
    Path { program: usize },
    /// The backplot's cut path so far (a read).
    Cut {},
    /// Run these lines (MDI) from where the tool stands, from READY.
    Mdi { text: String },
    /// Run program `program` from line `line` on (the tool goes there first), from READY.
    RunFrom { program: i16, line: u32 },
    /// Abandon the job being planned.
    Cancel {},
    /// Send this client at most `hz` frames a second (1 … 20; the newest each time): a page
    /// that draws 4 times a second need not take 20. Each frame carries the tool's recent
    /// points, so the cut path misses none.
    Frames { hz: f64 },
    /// The tool table's entry of tool `number` set (added where the table has none), from
    /// READY: its pocket (its number when left out), offsets x y z a b c (mm, degrees),
    /// diameter (mm) and comment; written to the tool table's file.
    Tool {
        number: u32,
        #[serde(default)]
        pocket: Option<u32>,
        offsets: [f64; 6],
        diameter: f64,
        #[serde(default)]
        comment: String,
    },
    /// Tool `number`'s entry removed from the tool table, from READY.
    ToolRemove { number: u32 },
}

impl Command {
    /// Whether it only reads (a watching client may send it).
    fn reads(&self) -> bool {
        matches!(
            self,
            Command::Text { .. } | Command::Path { .. } | Command::Cut {} | Command::Frames { .. }
        )
    }

    /// Whether it stops something: STOP, a jog's release, a cancel. Never dropped for the rate.
    fn stops(&self) -> bool {
        match self {
            Command::Stop {} | Command::Cancel {} => true,
            Command::Jog { x, y, .. } => *x == 0.0 && *y == 0.0,
            _ => false,
        }
    }
}

/// A client's allowance of messages: [`COMMANDS_PER_S`] a second on average, as many at once.
struct Budget {
    tokens: f64,
    at: Instant,
}

impl Budget {
    fn new() -> Budget {
        Budget {
            tokens: COMMANDS_PER_S,
            at: Instant::now(),
        }
    }

    /// Takes one message from the allowance; false when it is spent.
    fn take(&mut self) -> bool {
        let now = Instant::now();
        self.tokens = (self.tokens + now.duration_since(self.at).as_secs_f64() * COMMANDS_PER_S).min(COMMANDS_PER_S);
        self.at = now;
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

/// What a client did that was not carried out, counted; the first of each kind is logged.
#[derive(Default)]
struct Refusals {
    /// Commands without the token.
    watching: u64,
    /// Messages beyond the budget.
    throttled: u64,
    /// Messages that are not commands.
    malformed: u64,
    /// Commands that could not be carried out (no such program, a program runs, …).
    refused: u64,
}

/// Serves one WebSocket client: frames out, commands in, until it goes.
///
/// Long, and kept whole: one `select!` loop whose branches (a frame, a message, the jog's
/// refresh, a job's answer) share the client's state — its budget, its counters, its job.
async fn client(mut socket: WebSocket, peer: SocketAddr, commands: bool, shared: &Arc<Shared>) {
    let id = shared.next_client.fetch_add(1, Ordering::Relaxed);
    let mut frames = shared.frames.subscribe();
    if commands {
        info!("screen {peer}: connected (may command)");
    } else {
        shared.watch_log.info(peer.ip(), || {
            format!("screen {peer}: connected (watching only: no token)")
        });
    }
    let mut hello = shared.hello.clone();
    hello["commands"] = json!(commands);
    hello["alarms"] = json!(shared.alarms.history());
    hello["origins"] = json!(shared.jobs.as_ref().map(|d| d.offsets().origins));
    hello["tool_table"] = json!(shared.jobs.as_ref().and_then(|d| d.tools()).map(|k| tool_table_json(k)));
    if socket.send(Message::Text(hello.to_string().into())).await.is_err() {
        return;
    }
    let mut budget = Budget::new();
    let mut counts = Refusals::default();
    let mut cut_asked: Option<Instant> = None;
    // A job this client asked for is planned beside the loop, which goes on taking its
    // messages (a STOP, a Cancel) and sending frames; the reply comes here when it is done.
    let (job_done, mut job_replies) = tokio::sync::mpsc::channel::<Json>(1);
    let mut job_pending = false;
    // The frames this client takes: at most one per `frame_gap` (None: every one).
    let (mut frame_gap, mut frame_sent): (Option<Duration>, Option<Instant>) = (None, None);
    loop {
        tokio::select! {
            Some(reply) = job_replies.recv() => {
                job_pending = false;
                if reply["type"] == "refused" {
                    counts.refused += 1;
                }
                if socket.send(Message::Text(reply.to_string().into())).await.is_err() {
                    break;
                }
            },
            frame = frames.recv() => match frame {
                Ok(text) => {
                    // Frames beyond the client's rate are left out (the newest comes next);
                    // alarms and the like never are.
                    let is_frame = text.contains(r#""type":"frame""#);
                    if is_frame && frame_gap.is_some_and(|gap| frame_sent.is_some_and(|at| at.elapsed() < gap)) {
                        continue;
                    }
                    if is_frame {
                        frame_sent = Some(Instant::now());
                    }
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
                    let parsed = serde_json::from_str::<Command>(&text);
                    // What stops is never dropped; everything else spends the allowance.
                    if !parsed.as_ref().is_ok_and(Command::stops) && !budget.take() {
                        counts.throttled += 1;
                        if counts.throttled == 1 {
                            warn!("screen {peer}: more than {COMMANDS_PER_S} messages a second: the excess is dropped (counted from now)");
                        }
                        continue;
                    }
                    let reply = match parsed {
                        Ok(Command::Cut {}) if cut_asked.is_some_and(|at| at.elapsed() < CUT_EVERY) => {
                            counts.refused += 1;
                            Some(json!({"type": "refused", "why": "the cut path is sent once a second at most"}))
                        }
                        Ok(Command::Frames { hz }) => {
                            if (1.0..=20.0).contains(&hz) {
                                // A little under the gap, so that the frame due is not missed by
                                // a scheduling jitter.
                                frame_gap = (hz < 20.0).then(|| Duration::from_secs_f64(0.9 / hz));
                                None
                            } else {
                                counts.refused += 1;
                                Some(json!({"type": "refused", "why": format!("frames: 1 … 20 a second, got {hz}")}))
                            }
                        }
                        Ok(c) if c.reads() => {
                            if matches!(c, Command::Cut {}) {
                                cut_asked = Some(Instant::now());
                            }
                            shared.read(c)
                        }
                        Ok(c @ (Command::Mdi { .. } | Command::RunFrom { .. } | Command::TouchOff { .. } | Command::Step { .. } | Command::Load { .. } | Command::Tool { .. } | Command::ToolRemove { .. }))
                            if commands && (!matches!(c, Command::Load { .. }) || shared.replans_on_load()) =>
                        {
                            if job_pending {
                                counts.refused += 1;
                                Some(json!({"type": "refused", "why": "your last job is being planned (Cancel abandons it)"}))
                            } else {
                                job_pending = true;
                                let (shared, done) = (Arc::clone(shared), job_done.clone());
                                tokio::spawn(async move {
                                    let reply = shared.make_job(peer, c).await;
                                    if let Some(outcome) = super::job_news::JobOutcome::of_reply(&reply, &peer.to_string()) {
                                        shared.sink.report_job(outcome);
                                    }
                                    let _ = done.send(reply).await;
                                });
                                Some(json!({"type": "planning"}))
                            }
                        }
                        Ok(_) if !commands => {
                            counts.watching += 1;
                            if counts.watching == 1 {
                                warn!("screen {peer}: command refused: watching only (no token); further refusals are counted");
                            }
                            Some(json!({"type": "refused", "why": "watching only: commands need the token"}))
                        }
                        Ok(c) => shared.apply(id, peer, c).err().map(|why| {
                            counts.refused += 1;
                            json!({"type": "refused", "why": why})
                        }),
                        Err(e) => {
                            counts.malformed += 1;
                            if counts.malformed == 1 {
                                warn!("screen {peer}: a message that is not a command ({e}): {}; further ones are counted", crate::runtime::config::shorten(&text));
                            }
                            Some(json!({"type": "refused", "why": format!("not a command: {e}")}))
                        }
                    };
                    if let Some(reply) = reply
                        && socket.send(Message::Text(reply.to_string().into())).await.is_err()
                    {
                        break;
                    }
                }
                Some(Ok(Message::Close(_))) | None | Some(Err(_)) => break,
                Some(Ok(_)) => {}
            },
        }
    }
    shared.release_jog(id, peer, "connection closed");
    let Refusals {
        watching,
        throttled,
        malformed,
        refused,
    } = counts;
    if watching + throttled + malformed + refused > 0 {
        info!(
            "screen {peer}: disconnected; not carried out: {watching} commands without the token, {throttled} messages over the rate, {malformed} malformed, {refused} refused"
        );
    } else if commands {
        info!("screen {peer}: disconnected");
    } else {
        shared
            .watch_log
            .info(peer.ip(), || format!("screen {peer}: disconnected (watching)"));
    }
}

impl Shared {
    /// The most WebSocket clients that watch only: a quarter of the places (at least one) are
    /// kept for clients who may command. Without a token every client may command.
    fn watch_max(&self) -> usize {
        let max = self.options.max_clients;
        if self.options.access.token.is_none() {
            return max;
        }
        max - (max / 4).max(1).min(max)
    }

    /// A place for a WebSocket client (`commands`: it may command), if there is one.
    fn take_place(self: &Arc<Self>, commands: bool) -> Option<Place> {
        if !commands && self.watchers.fetch_add(1, Ordering::AcqRel) >= self.watch_max() {
            self.watchers.fetch_sub(1, Ordering::AcqRel);
            return None;
        }
        if self.clients.fetch_add(1, Ordering::AcqRel) >= self.options.max_clients {
            self.clients.fetch_sub(1, Ordering::AcqRel);
            if !commands {
                self.watchers.fetch_sub(1, Ordering::AcqRel);
            }
            return None;
        }
        Some(Place {
            shared: Arc::clone(self),
            watcher: !commands,
        })
    }

    /// A wrong token from `peer`: logged once per source and interval, answered after the
    /// source's back-off (the right token is answered at once).
    async fn guessed(&self, peer: SocketAddr) {
        let wait = self.guesses.refused(&peer.ip(), Instant::now());
        self.guess_log.warn(peer.ip(), || {
            format!(
                "screen {peer}: a wrong token: watching only (wrong tokens from {} are answered ever later, up to {} s)",
                peer.ip(),
                crate::runtime::backoff::LONGEST.as_secs()
            )
        });
        tokio::time::sleep(wait).await;
    }

    /// Answers a read: a window of a program's text, or its path.
    fn read(&self, command: Command) -> Option<Json> {
        Some(match command {
            Command::Text { program: k, from } => match self.served(k) {
                Some(p) => {
                    let (lines, total) = p.window(from);
                    json!({"type": "text", "program": k, "file": self.file(k), "from": from.max(1), "lines": lines, "total": total})
                }
                None => json!({"type": "refused", "why": format!("no program {k}")}),
            },
            Command::Path { program: k } => match k.checked_sub(1).and_then(|i| self.programs.get(i)) {
                Some(p) => json!({"type": "path", "program": k, "path": p.program.path}),
                None => match (self.job(k), self.spec(k)) {
                    (Some(job), _) => json!({"type": "path", "program": k, "path": preview(job.trajectory.as_ref())}),
                    (None, Some(_)) => {
                        json!({"type": "refused", "why": format!("job {k} was replaced: its plan is released")})
                    }
                    (None, None) => json!({"type": "refused", "why": format!("no program {k}")}),
                },
            },
            Command::Cut {} => match &self.cut {
                Some(cut) => cut.lock().unwrap_or_else(|p| p.into_inner()).json(),
                None => json!({"type": "refused", "why": "this run has no programs"}),
            },
            _ => return None,
        })
    }

    /// The plan of screen job `k`, if it was made and is not released.
    fn job(&self, k: usize) -> Option<std::sync::Arc<pkm_api::trajectory::NcJob>> {
        let library = self.jobs.as_ref()?.library();
        library.screen.job(library.screen_slot(i16::try_from(k).ok()?)?)
    }

    /// What screen job `k` was made of, if it was made.
    fn spec(&self, k: usize) -> Option<&pkm_api::screen_jobs::ScreenJobSpec> {
        self.jobs.as_ref()?.library().screen_spec(i16::try_from(k).ok()?)
    }

    /// The file name of program or job `k`.
    fn file(&self, k: usize) -> String {
        match k.checked_sub(1).and_then(|i| self.programs.get(i)) {
            Some(p) => p.program.file.clone(),
            None => self
                .jobs
                .as_ref()
                .and_then(|desk| {
                    let library = desk.library();
                    library.screen.file(library.screen_slot(i16::try_from(k).ok()?)?)
                })
                .map(str::to_string)
                .unwrap_or_default(),
        }
    }

    /// The text of program or job `k` as served: a job from a line is its program's text; an
    /// MDI job's few lines are counted on each request.
    fn served(&self, k: usize) -> Option<std::borrow::Cow<'_, Served>> {
        if let Some(p) = k.checked_sub(1).and_then(|i| self.programs.get(i)) {
            return Some(std::borrow::Cow::Borrowed(p));
        }
        match &self.spec(k)?.kind {
            pkm_api::screen_jobs::ScreenJobKind::FromLine { program, .. } => usize::try_from(*program)
                .ok()
                .and_then(|p| p.checked_sub(1))
                .and_then(|i| self.programs.get(i))
                .map(std::borrow::Cow::Borrowed),
            pkm_api::screen_jobs::ScreenJobKind::Mdi { text } => {
                Some(std::borrow::Cow::Owned(Served::new(ScreenProgram {
                    file: self.file(k),
                    text: super::jobs::mdi_program(text),
                    path: Vec::new(),
                    planned_s: 0.0,
                })))
            }
        }
    }

    /// Carries out a client's command; a refused one says why.
    fn apply(&self, id: u64, peer: SocketAddr, command: Command) -> Result<(), String> {
        match command {
            Command::Text { .. }
            | Command::Path { .. }
            | Command::Cut {}
            | Command::Mdi { .. }
            | Command::RunFrom { .. }
            | Command::TouchOff { .. }
            | Command::Step { .. }
            | Command::Tool { .. }
            | Command::ToolRemove { .. }
            | Command::Frames { .. } => {}
            Command::Cancel {} => {
                let cancelled = self
                    .jobs
                    .as_ref()
                    .is_some_and(|desk| desk.cancel("cancelled by the operator"));
                if !cancelled {
                    return Err("no job is being planned".into());
                }
                info!("screen {peer}: the job being planned is cancelled");
            }
            Command::Load { program } => {
                self.may_load(program).inspect_err(|why| {
                    info!("screen {peer}: load program {program} refused: {why}");
                })?;
                info!("screen {peer}: load program {program}");
                self.sink.update(|c| c.program = program);
            }
            Command::Override { feed, rapid, spindle } => {
                let check = |what: &str, v: Option<i16>, range: &std::ops::RangeInclusive<i16>| match v {
                    Some(v) if !range.contains(&v) => Err(format!(
                        "{what} override {v} % is outside {} … {} %",
                        range.start(),
                        range.end()
                    )),
                    _ => Ok(()),
                };
                check("feed", feed, &FEED_OVERRIDE_RANGE)?;
                check("rapid", rapid, &RAPID_OVERRIDE_RANGE)?;
                check("spindle", spindle, &SPINDLE_OVERRIDE_RANGE)?;
                let now = self.sink.current();
                let (feed, rapid, spindle) = (
                    feed.unwrap_or(now.feed_override),
                    rapid.unwrap_or(now.rapid_override),
                    spindle.unwrap_or(now.spindle_override),
                );
                if (feed, rapid, spindle) != (now.feed_override, now.rapid_override, now.spindle_override) {
                    info!(
                        "screen {peer}: feed override {feed} %, rapid override {rapid} %, spindle override {spindle} %"
                    );
                    self.sink.update(|c| {
                        c.feed_override = feed;
                        c.rapid_override = rapid;
                        c.spindle_override = spindle;
                    });
                }
            }
            Command::SingleBlock { on } => {
                info!("screen {peer}: single block {}", if on { "on" } else { "off" });
                self.sink.update(|c| c.single_block = on);
            }
            Command::ToolChanged { tool, change } => {
                let (waiting, asked) = unpack(self.tool_asked.load(Ordering::Relaxed));
                let refused = if !self.tool_change.load(Ordering::Relaxed) {
                    Some(format!(
                        "the confirmation of tool {tool} (change {change}) is refused: no tool change waits"
                    ))
                } else if (tool, change) != (asked, waiting) {
                    Some(format!(
                        "the confirmation of tool {tool} (change {change}) is refused: change {waiting} waits, for tool {asked}"
                    ))
                } else {
                    None
                };
                if let Some(why) = refused {
                    info!("screen {peer}: {why}");
                    return Err(why);
                }
                info!("screen {peer}: tool change {change} confirmed: tool {tool} in the spindle");
                self.sink.update(|c| c.tool_confirm = change);
            }
            Command::Acknowledge {} => {
                if !self.in_error.load(Ordering::Relaxed) {
                    return Err("there is no error to acknowledge: the machine is not in ERROR".into());
                }
                info!("screen {peer}: acknowledge");
                self.alarms.acknowledging(peer.to_string());
                self.sink.update(|c| c.acknowledgements += 1);
            }
            Command::Stop {} => {
                info!("screen {peer}: STOP");
                // In ERROR a STOP press acknowledges, as the panel's does.
                if self.in_error.load(Ordering::Relaxed) {
                    self.alarms.acknowledging(peer.to_string());
                }
                self.sink.update(|c| c.presses[press::STOP] += 1);
                // A job being planned would find the machine in ERROR; it is abandoned now.
                if self.jobs.as_ref().is_some_and(|desk| desk.cancel("STOP pressed")) {
                    info!("screen {peer}: the job being planned is abandoned (STOP)");
                }
            }
            Command::Axes {} => {
                info!("screen {peer}: axis button");
                self.sink.update(|c| c.presses[press::AXES] += 1);
            }
            Command::Reference {} => {
                if !self.ready.load(Ordering::Relaxed) {
                    return Err("the machine references again from READY only: end the jog or the program first (after an error, Acknowledge references it)".into());
                }
                info!("screen {peer}: reference again");
                self.sink.update(|c| c.presses[press::REFERENCE] += 1);
            }
            Command::Program { what } => {
                let k = match what.as_str() {
                    "start" => 0,
                    "hold" => 1,
                    "resume" => 2,
                    other => {
                        return Err(format!(
                            "no program command \"{}\"",
                            crate::runtime::config::shorten(other)
                        ));
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

    /// Whether a client holds a jog now.
    fn jog_held(&self) -> bool {
        self.jog_owner.lock().unwrap_or_else(|p| p.into_inner()).is_some()
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

/// A tool change's number and tool in one word (for one atomic load).
fn pack(change: i32, tool: i32) -> i64 {
    (i64::from(change) << 32) | i64::from(tool as u32)
}

/// The change's number and tool of [`pack`].
fn unpack(word: i64) -> (i32, i32) {
    ((word >> 32) as i32, word as u32 as i32)
}

#[cfg(test)]
mod tests {
    use super::super::served::MAX_LINE_CHARS;
    use super::*;
    use proptest::prelude::*;

    fn served(text: &str) -> Served {
        Served::new(ScreenProgram {
            file: "p.ngc".into(),
            text: text.into(),
            path: Vec::new(),
            planned_s: 0.0,
        })
    }

    /// What a window must hold: the text's lines from `from` on, read from its start.
    fn read_through(text: &str, from: usize) -> (Vec<String>, usize) {
        let lines = text
            .lines()
            .skip(from.max(1) - 1)
            .take(TEXT_WINDOW)
            .map(str::to_string)
            .collect();
        (lines, text.lines().count())
    }

    #[test]
    fn windows_across_checkpoints_hold_the_lines_they_name() {
        let text: String = (1..=1000).map(|i| format!("N{i} G1 X{i}\r\n")).collect();
        let p = served(&text);
        assert_eq!(p.total, 1000);
        for from in [0, 1, 2, 399, 400, 401, 402, 799, 800, 801, 999, 1000, 1001, 5000] {
            assert_eq!(p.window(from), read_through(&text, from), "from {from}");
        }
        let (lines, _) = p.window(401);
        assert_eq!(lines.first().map(String::as_str), Some("N401 G1 X401"));
        assert_eq!(lines.len(), 400);
    }

    #[test]
    fn a_long_line_is_cut() {
        let text = format!("{}\nG0 X1\n", "é".repeat(MAX_LINE_CHARS + 5));
        let (lines, total) = served(&text).window(1);
        assert_eq!(total, 2);
        assert_eq!(lines[0], format!("{}…", "é".repeat(MAX_LINE_CHARS)));
        assert_eq!(lines[1], "G0 X1");
    }

    proptest! {
        #[test]
        fn a_window_is_the_lines_read_from_the_start(
            lines in proptest::collection::vec("[a-z \r]{0,6}", 0..1300),
            ending in prop::sample::select(vec!["\n", "\r\n"]),
            last_ended in any::<bool>(),
            from in 0usize..1400,
        ) {
            let mut text = lines.join(ending);
            if last_ended {
                text.push_str(ending);
            }
            prop_assert_eq!(served(&text).window(from), read_through(&text, from));
        }
    }
}
