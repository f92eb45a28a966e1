//! The OPC UA server of a real-time run, on the runtime's tokio runtime: built from the run's
//! process image, fed by [`FrameFeed`] (the frames the cycle publishes for the screen, so it
//! never touches the cyclic thread), commanding through the screen's [`CommandSink`].

use std::os::unix::fs::PermissionsExt;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use opcua::crypto::SecurityPolicy;
use opcua::server::{ServerBuilder, ServerEndpoint, ServerHandle};
use opcua::types::{BuildInfo, DataValue, MessageSecurityMode, NodeId};
use tokio::net::TcpListener;
use tracing::warn;

use super::OpcUaOptions;
use super::alarm_methods::AlarmMethods;
use super::auth::Auth;
use super::conditions::Conditions;
use super::history::History;
use super::methods::CallRate;
use super::nodes::{Commander, PlcNodeManager};
use super::space::{NAMESPACE, Space, SpaceInfo};
use crate::runtime::frame::FrameFeed;
use crate::services::hmi::commands::CommandSink;

/// The endpoints' path: the server's root.
const ENDPOINT_PATH: &str = "/";

/// How long a client may take to say hello after connecting (s).
const HELLO_TIMEOUT_S: u32 = 5;

/// How long a connection may hold no session before the gate closes it: longer than a login
/// refused several times waits for its answer (the back-off reaches 10 s).
const SESSIONLESS: Duration = Duration::from_secs(20);

/// What the run planned with, for the machine tool view: the tool table as it changes, the
/// programs and screen jobs as planned.
pub struct Planned {
    /// The tool table.
    pub tools: Option<Arc<crate::runtime::tool_table::ToolTableKeeper>>,
    /// The run's programs and screen jobs.
    pub library: Option<pkm_api::library::NcLibrary>,
}

/// Builds the server for `info` and starts it behind `public` (inside the tokio runtime): the
/// address space from the first frame, a task that writes every newer frame's changes, the
/// methods that command through `sink`, the gate that bounds the connections. Returns the
/// endpoint URL clients connect to.
///
/// Long, and kept whole: it is the server builder's one chain of settings (endpoints, security
/// policies, limits, the node manager) followed by the tasks that serve it; split, each part
/// would hand the half-built server to the next.
pub fn start(
    options: &OpcUaOptions,
    public: TcpListener,
    info: SpaceInfo,
    feed: FrameFeed,
    sink: CommandSink,
    main_period_ns: u64,
    planned: Planned,
) -> Result<String, String> {
    let port = public.local_addr().map_err(|e| e.to_string())?.port();
    // The server itself listens on a loopback port of its own, behind the gate.
    let listener = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.set_nonblocking(true).map(|()| l))
        .and_then(TcpListener::from_std)
        .map_err(|e| format!("cannot listen on loopback for the gate: {e}"))?;
    let inner = listener.local_addr().map_err(|e| e.to_string())?;
    let url = format!("opc.tcp://{}:{port}{ENDPOINT_PATH}", url_host(&options.host));
    let main_ms = (main_period_ns as f64 / 1e6).max(1.0);
    let anonymous = vec![opcua::server::ANONYMOUS_USER_TOKEN_ID.to_string()];
    let pki = options.pki_of(&info.machine);
    // One certificate per machine: its URI names the computer and the machine, and the
    // certificate made for it says so (its common name is the application's name).
    let application_uri = format!("urn:{}:pkm-plc:{}", host_name(), info.machine);
    own_certificate_fits(&pki, &application_uri)?;
    let mut builder = ServerBuilder::new()
        .application_name(format!("pkm-plc ({})", info.machine))
        .application_uri(application_uri)
        .product_uri("urn:pkm-plc")
        .build_info(BuildInfo {
            product_uri: "urn:pkm-plc".into(),
            manufacturer_name: "pkm-plc".into(),
            product_name: "pkm-plc soft-PLC".into(),
            software_version: env!("CARGO_PKG_VERSION").into(),
            build_number: env!("CARGO_PKG_VERSION").into(),
            build_date: opcua::types::DateTime::now(),
        })
        .discovery_urls(vec![url.clone()])
        .host(options.host.clone())
        .port(port)
        .pki_dir(pki.clone())
        .create_sample_keypair(true)
        .trust_client_certs(false)
        .hello_timeout(HELLO_TIMEOUT_S)
        .max_sessions(options.max_sessions)
        .diagnostics_enabled(false)
        // Subscriptions are looked at five times per main cycle, and publish at most once per
        // main cycle: the rate data changes come at.
        .subscription_poll_interval_ms((main_period_ns / 5_000_000).max(1))
        .with_authenticator(Arc::new(Auth::new(options.users.clone())))
        .with_node_manager(super::nodes::builder(super::companion::imports()?))
        .add_endpoint(
            "basic256sha256_sign",
            ServerEndpoint::new(
                ENDPOINT_PATH,
                SecurityPolicy::Basic256Sha256,
                MessageSecurityMode::Sign,
                &anonymous,
            ),
        )
        .add_endpoint(
            "basic256sha256_sign_encrypt",
            ServerEndpoint::new(
                ENDPOINT_PATH,
                SecurityPolicy::Basic256Sha256,
                MessageSecurityMode::SignAndEncrypt,
                &anonymous,
            ),
        )
        // The newest policy as well, for clients that no longer offer Basic256Sha256.
        .add_endpoint(
            "aes256sha256rsapss_sign_encrypt",
            ServerEndpoint::new(
                ENDPOINT_PATH,
                SecurityPolicy::Aes256Sha256RsaPss,
                MessageSecurityMode::SignAndEncrypt,
                &anonymous,
            ),
        );
    if options.loopback() {
        // Unsecured on loopback only; a password still travels encrypted with the server's key.
        let mut none = ServerEndpoint::new_none(ENDPOINT_PATH, &anonymous);
        none.password_security_policy = Some("Basic256Sha256".into());
        builder = builder.add_endpoint("none", none);
    }
    let limits = builder.limits_mut();
    limits.subscriptions.min_publishing_interval_ms = main_ms;
    limits.subscriptions.min_sampling_interval_ms = main_ms;
    private_store(&pki)?;
    let (server, handle) = builder.build()?;
    handle
        .session_manager()
        .write()
        .set_max_not_users(super::max_not_users(options.max_sessions));
    // The key the library may just have made: the owner's alone.
    let key = pki.join("private/private.pem");
    if key.exists() {
        std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o600))
            .map_err(|e| format!("{}: {e}", key.display()))?;
    }
    let manager = handle
        .node_managers()
        .get_of_type::<PlcNodeManager>()
        .ok_or("the node manager is missing (a broken invariant of the server's build)")?;
    let ns = handle
        .get_namespace_index(NAMESPACE)
        .ok_or("the namespace is missing (a broken invariant of the server's build)")?;

    let first = feed.latest();
    let sources = super::machine_tool::Sources {
        programs: info.programs.clone(),
        jobs: Some(sink.job_news()),
        tools: planned.tools,
        library: planned.library,
    };
    let mut space = {
        let mut address_space = manager.address_space().write();
        Space::build(&mut address_space, ns, &info, &first, sources)
    };
    // What becomes of the screen's jobs (JobRefused), read before the sink goes to the methods.
    let job_news = sink.job_news();
    let commander = Commander {
        methods: space.methods.iter().map(|(m, node)| (node.clone(), *m)).collect(),
        feed: feed.clone(),
        sink,
        programs: info.programs.clone(),
        rate: Mutex::new(CallRate::new(Instant::now())),
    };
    if !manager.inner().set_commander(commander) {
        return Err("the methods were given twice (a broken invariant of the server's start)".into());
    }
    // The alarms and conditions, and who carries out their methods.
    let conditions = Arc::new(Mutex::new(Conditions::new(
        (space.object.clone(), info.machine.clone()),
        space.reason_index,
        |kind| {
            space
                .alarms
                .iter()
                .find(|(k, _)| *k == kind)
                .map(|(_, node)| node.clone())
                .unwrap_or_else(NodeId::null)
        },
    )));
    let methods = AlarmMethods {
        conditions: Arc::clone(&conditions),
        manager: Arc::clone(&manager),
        emitters: space.emitters(),
    };
    if handle.info().condition_methods.set(Arc::new(methods)).is_err() {
        return Err("the conditions' methods were given twice (a broken invariant of the server's start)".into());
    }
    // The history of the main variables.
    let history = {
        let mut h = History::default();
        for (node, kind) in &space.historized {
            h.keep(node.clone(), *kind);
        }
        Arc::new(Mutex::new(h))
    };
    if !manager.inner().set_history(Arc::clone(&history)) {
        return Err("the history was given twice (a broken invariant of the server's start)".into());
    }
    spawn_job_conditions(job_news, Arc::clone(&conditions), handle.clone(), space.emitters());
    let kept = Kept { conditions, history };
    // The first frame's values (state texts, figures) before any client reads.
    publish(&manager, &handle, &mut space, &kept, &first);

    let (pump_manager, pump_handle) = (Arc::clone(&manager), handle.clone());
    let mut frames = feed;
    tokio::spawn(async move {
        let mut publisher = Publisher {
            manager: pump_manager,
            handle: pump_handle,
            space,
            kept,
        };
        let mut supervisor = Supervisor::default();
        while let Some(frame) = frames.next().await {
            if publisher.handle.token().is_cancelled() {
                break;
            }
            supervisor.frame(Instant::now(), &mut publisher, &frame);
        }
    });
    tokio::spawn(async move {
        if let Err(e) = server.run_with(listener).await {
            warn!("OPC UA server: {e}");
        }
    });
    let bounds = super::gate::Bounds {
        max: super::max_connections(options.max_sessions),
        hello: Duration::from_secs(u64::from(HELLO_TIMEOUT_S)),
        sessionless: SESSIONLESS,
    };
    let sessions = handle.clone();
    let standing: super::gate::StandingOf = Arc::new(move |from| sessions.session_manager().read().standing(&from));
    super::gate::spawn(public, inner, bounds, standing);
    Ok(url)
}

/// What publishes a frame's values, and marks them all bad when it cannot.
trait Publish {
    /// Publishes `frame` (it may panic: a fault of the server).
    fn publish(&mut self, frame: &crate::runtime::frame::Frame);
    /// Marks every value bad (a publication failed).
    fn mark_bad(&mut self);
}

/// The server's publisher: the address space's values from each frame.
struct Publisher {
    manager: Arc<PlcNodeManager>,
    handle: ServerHandle,
    space: Space,
    kept: Kept,
}

impl Publish for Publisher {
    fn publish(&mut self, frame: &crate::runtime::frame::Frame) {
        publish(&self.manager, &self.handle, &mut self.space, &self.kept, frame);
    }

    /// Every value BadInternalError, and what was published forgotten: the next frame that
    /// publishes writes every value again, good.
    fn mark_bad(&mut self) {
        self.space.forget();
        let now = opcua::types::DateTime::now();
        let bad = DataValue {
            value: None,
            status: Some(opcua::types::StatusCode::BadInternalError),
            source_timestamp: Some(now),
            source_picoseconds: None,
            server_timestamp: Some(now),
            server_picoseconds: None,
        };
        let nodes = self.space.value_nodes();
        if let Err(e) = self.manager.set_values(
            self.handle.subscriptions(),
            nodes.iter().map(|id| (id, None, bad.clone())),
        ) {
            warn!("OPC UA: the values could not be marked bad: {e}");
        }
    }
}

/// The first pause before a failed publication is tried again, and the longest.
const RETRY_FIRST: Duration = Duration::from_secs(1);
const RETRY_MAX: Duration = Duration::from_secs(60);

/// Supervises the publication of every frame. A publication that panics is caught — the task
/// that publishes goes on (before, it ended, and every value stayed frozen with status Good) —,
/// every value is marked bad and the fault logged once; while it keeps failing it is tried
/// again after a pause that doubles from [`RETRY_FIRST`] to [`RETRY_MAX`] (each try's panic
/// message goes to the log); once a frame is published again the values are good.
#[derive(Debug, Default)]
struct Supervisor {
    /// While publications fail: when to try again, and the pause before that.
    failing: Option<(Instant, Duration)>,
}

impl Supervisor {
    /// `frame`, arrived at `now`, through `publisher`.
    fn frame(&mut self, now: Instant, publisher: &mut impl Publish, frame: &crate::runtime::frame::Frame) {
        if self.failing.is_some_and(|(retry_at, _)| now < retry_at) {
            return;
        }
        let tried = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| publisher.publish(frame)));
        match tried {
            Ok(()) => {
                if self.failing.take().is_some() {
                    tracing::info!("OPC UA: frames are published again: the values are good");
                }
            }
            Err(panic) => {
                let pause = match self.failing {
                    None => {
                        publisher.mark_bad();
                        tracing::error!(
                            "OPC UA: publishing a frame failed (a fault of the server: please report it): {}; every \
                             value is BadInternalError until a frame is published again",
                            crate::runtime::service_mode::panic_message(panic.as_ref())
                        );
                        RETRY_FIRST
                    }
                    Some((_, pause)) => (pause * 2).min(RETRY_MAX),
                };
                self.failing = Some((now + pause, pause));
            }
        }
    }
}

/// Raises and clears `JobRefused` as the screen's jobs are refused and made (their `news`),
/// emitting its events on `emitters`, until the server stops.
fn spawn_job_conditions(
    mut news: tokio::sync::watch::Receiver<crate::services::hmi::job_news::JobNews>,
    conditions: Arc<Mutex<Conditions>>,
    handle: ServerHandle,
    emitters: super::emitters::Emitters,
) {
    tokio::spawn(async move {
        while news.changed().await.is_ok() && !handle.token().is_cancelled() {
            let Some(outcome) = news.borrow_and_update().latest.clone() else {
                continue;
            };
            let event = conditions
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .job(&outcome, opcua::types::DateTime::now());
            if let Some(event) = event {
                emitters.emit(
                    &mut handle.subscriptions().event_notifier(),
                    &event as &dyn opcua::nodes::Event,
                );
            }
        }
    });
}

/// Makes the certificate store's directories, the private key's readable by its owner only (the
/// server's key is made there on first use).
fn private_store(pki: &std::path::Path) -> Result<(), String> {
    let private = pki.join("private");
    std::fs::create_dir_all(&private)
        .map_err(|e| format!("cannot make the certificate store {}: {e}", private.display()))?;
    std::fs::set_permissions(&private, std::fs::Permissions::from_mode(0o700))
        .map_err(|e| format!("{}: {e}", private.display()))
}

/// Refuses a store whose certificate was made for another application (another machine's, or
/// one made before certificates were per machine): clients check the server's certificate
/// against its application URI, and a store shared by two machines would give a client trusted
/// for one the other's trust too.
fn own_certificate_fits(pki: &std::path::Path, application_uri: &str) -> Result<(), String> {
    let cert = pki.join("own/cert.der");
    let Ok(der) = std::fs::read(&cert) else {
        // None yet: the library makes one for this machine.
        return Ok(());
    };
    let x509 =
        opcua::crypto::X509::from_der(&der).map_err(|e| format!("{}: not a certificate: {e}", cert.display()))?;
    x509.is_application_uri_valid(application_uri).map_err(|_| {
        format!(
            "{}: the certificate there was made for another server ({}), not for {application_uri}: \
             give this machine a certificate store of its own (--opcua-pki DIR), or remove {}/own and {}/private \
             to have one made for it",
            pki.display(),
            x509.subject_name(),
            pki.display(),
            pki.display()
        )
    })
}

/// This computer's name (`localhost` where it cannot be read).
pub fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|n| n.trim().to_string())
        .ok()
        .filter(|n| !n.is_empty())
        .unwrap_or_else(|| "localhost".into())
}

/// The host as it stands in a URL (an IPv6 address in brackets).
fn url_host(host: &str) -> String {
    if host.contains(':') {
        format!("[{host}]")
    } else {
        host.to_string()
    }
}

/// What the server keeps of the frames besides the nodes' values.
struct Kept {
    /// The alarms and conditions.
    conditions: Arc<Mutex<Conditions>>,
    /// The main variables' history.
    history: Arc<Mutex<History>>,
}

/// Writes `frame`'s changes, records the historized ones and notifies the subscriptions; the
/// conditions it changes raise their events.
fn publish(
    manager: &PlcNodeManager,
    handle: &ServerHandle,
    space: &mut Space,
    kept: &Kept,
    frame: &crate::runtime::frame::Frame,
) {
    let changes = {
        let mut address_space = manager.address_space().write();
        space.changes(&mut address_space, frame)
    };
    {
        let mut history = kept.history.lock().unwrap_or_else(|p| p.into_inner());
        for (node, value) in &changes {
            if let (Some(v), Some(at)) = (&value.value, value.source_timestamp)
                && history.keeps(node)
            {
                history.record(node, at, v);
            }
        }
    }
    let conditions = &kept.conditions;
    if frame.seq > 0 {
        let at = changes
            .first()
            .and_then(|(_, v)| v.source_timestamp)
            .unwrap_or_else(opcua::types::DateTime::now);
        let events = conditions.lock().unwrap_or_else(|p| p.into_inner()).observe(frame, at);
        if !events.is_empty() {
            let emitters = space.emitters();
            let mut notifier = handle.subscriptions().event_notifier();
            for e in &events {
                emitters.emit(&mut notifier, e as &dyn opcua::nodes::Event);
            }
        }
    }
    let (ids, values): (Vec<NodeId>, Vec<DataValue>) = changes.into_iter().unzip();
    if let Err(e) = manager.set_values(
        handle.subscriptions(),
        ids.iter().zip(values).map(|(id, v)| (id, None, v)),
    ) {
        warn!("OPC UA: a frame's values could not be written: {e}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::frame::Frame;
    use crate::runtime::snapshot::Snapshot;

    /// Publishes by writing down each frame's number; panics on the frames of `broken`.
    #[derive(Default)]
    struct Recorder {
        broken: std::ops::Range<u64>,
        published: Vec<u64>,
        marked_bad: usize,
    }

    impl Publish for Recorder {
        fn publish(&mut self, frame: &Frame) {
            if self.broken.contains(&frame.seq) {
                panic!("frame {} cannot be published", frame.seq);
            }
            self.published.push(frame.seq);
        }

        fn mark_bad(&mut self) {
            self.marked_bad += 1;
        }
    }

    fn frame(seq: u64) -> Frame {
        Frame {
            seq,
            status: Snapshot::default(),
            image: Vec::new(),
            bus_fault: false,
            bus_cause: String::new(),
            published_unix_us: 0,
        }
    }

    /// Frames every 50 ms; those of seconds 1 … 4 panic. The values are marked bad once, at the
    /// first; tries come after 1 s, then 2 s; the first frame that publishes again is the
    /// first tried after the fault ended; the publishing never stops.
    #[test]
    fn a_publication_that_panics_marks_the_values_bad_once_and_publishing_goes_on() {
        let mut recorder = Recorder {
            broken: 20..80,
            ..Recorder::default()
        };
        let mut supervisor = Supervisor::default();
        let start = Instant::now();
        for seq in 1..=200 {
            supervisor.frame(start + Duration::from_millis(50 * seq), &mut recorder, &frame(seq));
        }
        assert_eq!(recorder.marked_bad, 1);
        // Tried at frame 20 (failed), 40 (1 s on: failed), 80 (2 s on: published again).
        let tried_again: Vec<u64> = recorder
            .published
            .iter()
            .copied()
            .filter(|&s| s >= 20)
            .take(2)
            .collect();
        assert_eq!(tried_again, [80, 81]);
        assert_eq!(
            recorder.published.len(),
            19 + (200 - 79),
            "every frame before and after"
        );
        assert!(supervisor.failing.is_none());
    }
}
