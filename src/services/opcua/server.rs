//! The OPC UA server of a real-time run, on the runtime's tokio runtime: built from the run's
//! process image, fed by [`FrameFeed`] (the frames the cycle publishes for the screen, so it
//! never touches the cyclic thread), commanding through the screen's [`CommandSink`].

use std::os::unix::fs::PermissionsExt;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use opcua::crypto::SecurityPolicy;
use opcua::server::{ServerBuilder, ServerEndpoint, ServerHandle};
use opcua::types::{BuildInfo, DataValue, MessageSecurityMode, NodeId, StatusCode, Variant};
use tokio::net::TcpListener;
use tracing::warn;

use super::OpcUaOptions;
use super::auth::Auth;
use super::nodes::{Commander, PlcNodeManager};
use super::space::{Method, NAMESPACE, Space, SpaceInfo};
use crate::runtime::frame::FrameFeed;
use crate::services::hmi::commands::{CommandSink, press};

/// The endpoints' path: the server's root.
const ENDPOINT_PATH: &str = "/";

/// How long a client may take to say hello after connecting (s).
const HELLO_TIMEOUT_S: u32 = 5;

/// Connections held beyond the sessions: clients that only ask for the endpoints, one opening
/// a session while another closes.
const SPARE_CONNECTIONS: usize = 4;

/// Builds the server for `info` and starts it behind `public` (inside the tokio runtime): the
/// address space from the first frame, a task that writes every newer frame's changes, the
/// methods that command through `sink`, the gate that bounds the connections. Returns the
/// endpoint URL clients connect to.
pub fn start(
    options: &OpcUaOptions,
    public: TcpListener,
    info: SpaceInfo,
    feed: FrameFeed,
    sink: CommandSink,
    main_period_ns: u64,
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
    let mut builder = ServerBuilder::new()
        .application_name(format!("pkm-plc ({})", info.machine))
        // One certificate per computer, whichever machine runs: the URI names the computer.
        .application_uri(format!("urn:{}:pkm-plc", host_name()))
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
        .pki_dir(options.pki_dir.clone())
        .create_sample_keypair(true)
        .trust_client_certs(false)
        .hello_timeout(HELLO_TIMEOUT_S)
        .max_sessions(options.max_sessions)
        .diagnostics_enabled(false)
        // Subscriptions are looked at five times per main cycle, and publish at most once per
        // main cycle: the rate data changes come at.
        .subscription_poll_interval_ms((main_period_ns / 5_000_000).max(1))
        .with_authenticator(Arc::new(Auth::new(options.users.clone())))
        .with_node_manager(super::nodes::builder())
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
    private_store(&options.pki_dir)?;
    let (server, handle) = builder.build()?;
    // The key the library may just have made: the owner's alone.
    let key = options.pki_dir.join("private/private.pem");
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
    let mut space = {
        let mut address_space = manager.address_space().write();
        Space::build(&mut address_space, ns, &info, &first)
    };
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
    // The first frame's values (state texts, figures) before any client reads.
    publish(&manager, &handle, &mut space, &first);

    let (pump_manager, pump_handle) = (Arc::clone(&manager), handle.clone());
    let mut frames = feed;
    tokio::spawn(async move {
        while let Some(frame) = frames.next().await {
            if pump_handle.token().is_cancelled() {
                break;
            }
            publish(&pump_manager, &pump_handle, &mut space, &frame);
        }
    });
    tokio::spawn(async move {
        if let Err(e) = server.run_with(listener).await {
            warn!("OPC UA server: {e}");
        }
    });
    super::gate::spawn(
        public,
        inner,
        super::gate::Bounds::new(
            options.max_sessions + SPARE_CONNECTIONS,
            Duration::from_secs(u64::from(HELLO_TIMEOUT_S)),
        ),
    );
    Ok(url)
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

/// Writes `frame`'s changes and notifies the subscriptions.
fn publish(manager: &PlcNodeManager, handle: &ServerHandle, space: &mut Space, frame: &crate::runtime::frame::Frame) {
    let changes = {
        let mut address_space = manager.address_space().write();
        space.changes(&mut address_space, frame)
    };
    let (ids, values): (Vec<NodeId>, Vec<DataValue>) = changes.into_iter().unzip();
    if let Err(e) = manager.set_values(
        handle.subscriptions(),
        ids.iter().zip(values).map(|(id, v)| (id, None, v)),
    ) {
        warn!("OPC UA: a frame's values could not be written: {e}");
    }
}

/// The most method calls taken per second, all sessions together: far more than an operator or
/// a SCADA sends; a client calling in a loop is refused (`BadTooManyOperations`) rather than
/// flooding the process image and the log.
pub const MAX_CALLS_PER_S: u32 = 20;

/// Counts method calls per second against [`MAX_CALLS_PER_S`].
#[derive(Debug)]
pub struct CallRate {
    window: Instant,
    calls: u32,
    refused: u32,
}

impl CallRate {
    /// A rate whose first window starts `now`.
    pub fn new(now: Instant) -> CallRate {
        CallRate {
            window: now,
            calls: 0,
            refused: 0,
        }
    }

    /// Whether a call at `now` is taken. Refusals are logged once per window, as a count.
    pub fn allow(&mut self, now: Instant) -> bool {
        if now.duration_since(self.window) >= Duration::from_secs(1) {
            if self.refused > 0 {
                warn!(
                    "OPC UA: {} method calls refused in a second: at most {MAX_CALLS_PER_S} are taken",
                    self.refused
                );
            }
            *self = CallRate::new(now);
        }
        self.calls += 1;
        let allowed = self.calls <= MAX_CALLS_PER_S;
        if !allowed {
            self.refused += 1;
        }
        allowed
    }
}

/// Carries out `method` with `args` in main state `state`: what was done, or the status code
/// and why not.
pub fn command(
    method: Method,
    args: &[Variant],
    state: &str,
    programs: &[String],
    sink: &CommandSink,
) -> Result<String, (StatusCode, String)> {
    let invalid_state = |why: String| Err((StatusCode::BadInvalidState, why));
    match method {
        Method::Stop => {
            if state == "ERROR" {
                return invalid_state("the machine is in ERROR already; Acknowledge acknowledges the error".into());
            }
            sink.update(|c| c.presses[press::STOP] += 1);
            Ok("STOP pressed".into())
        }
        Method::Acknowledge => {
            if state != "ERROR" {
                return invalid_state(format!("there is no error to acknowledge: the machine is in {state}"));
            }
            sink.update(|c| c.acknowledgements += 1);
            Ok("the error acknowledged (STOP pressed once released)".into())
        }
        Method::Start | Method::Hold | Method::Resume => {
            // As the program's automaton takes them: start from READY, hold and resume in AUTO.
            let (k, from) = match method {
                Method::Start => (0, "READY"),
                Method::Hold => (1, "AUTO"),
                _ => (2, "AUTO"),
            };
            if state != from {
                return invalid_state(format!(
                    "the machine is in {state}: a program {} in {from}",
                    match method {
                        Method::Start => "starts",
                        Method::Hold => "is held",
                        _ => "resumes",
                    }
                ));
            }
            sink.update(|c| c.presses[press::NC[k]] += 1);
            Ok(format!("program {} pressed", method.name().to_lowercase()))
        }
        Method::Load => {
            let Some(Variant::Int16(n)) = args.first() else {
                return Err((
                    StatusCode::BadInvalidArgument,
                    "Load takes the program's number (Int16)".into(),
                ));
            };
            let n = *n;
            let known = usize::try_from(n).is_ok_and(|k| (1..=programs.len()).contains(&k));
            if !known {
                return Err((
                    StatusCode::BadOutOfRange,
                    format!("no program {n}: the run has {}", programs.len()),
                ));
            }
            if state == "AUTO" {
                return invalid_state("a program runs: another is loaded once it has ended or stopped".into());
            }
            sink.update(|c| c.program = n);
            Ok(format!("program {n} ({}) loaded", programs[n as usize - 1]))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn method_calls_beyond_the_rate_are_refused_until_the_next_second() {
        let start = Instant::now();
        let mut rate = CallRate::new(start);
        let taken = (0..30).filter(|_| rate.allow(start)).count();
        assert_eq!(taken, MAX_CALLS_PER_S as usize);
        assert!(!rate.allow(start + Duration::from_millis(999)));
        assert!(
            rate.allow(start + Duration::from_secs(1)),
            "a new second takes calls again"
        );
    }

    #[test]
    fn methods_check_the_state_and_their_argument() {
        let (_bus, sink) =
            crate::services::hmi::commands::HmiBus::new(Box::new(crate::runtime::bus::NoBus), 0, 500_000_000);
        let programs = vec!["programs/a.ngc".to_string()];
        let run = |m: Method, args: &[Variant], state: &str| command(m, args, state, &programs, &sink);
        assert_eq!(run(Method::Stop, &[], "READY"), Ok("STOP pressed".into()));
        assert_eq!(sink.current().presses[press::STOP], 1);
        assert_eq!(
            run(Method::Stop, &[], "ERROR"),
            Err((
                StatusCode::BadInvalidState,
                "the machine is in ERROR already; Acknowledge acknowledges the error".into()
            ))
        );
        assert_eq!(sink.current().presses[press::STOP], 1, "no press for a refused call");
        assert!(run(Method::Acknowledge, &[], "ERROR").is_ok());
        assert_eq!(sink.current().acknowledgements, 1);
        assert_eq!(
            run(Method::Start, &[], "AUTO"),
            Err((
                StatusCode::BadInvalidState,
                "the machine is in AUTO: a program starts in READY".into()
            ))
        );
        assert!(run(Method::Hold, &[], "AUTO").is_ok());
        assert_eq!(
            run(Method::Load, &[Variant::Int16(2)], "READY"),
            Err((StatusCode::BadOutOfRange, "no program 2: the run has 1".into()))
        );
        assert_eq!(
            run(Method::Load, &[Variant::Int32(1)], "READY"),
            Err((
                StatusCode::BadInvalidArgument,
                "Load takes the program's number (Int16)".into()
            ))
        );
        assert_eq!(
            run(Method::Load, &[Variant::Int16(1)], "READY"),
            Ok("program 1 (programs/a.ngc) loaded".into())
        );
        assert_eq!(sink.current().program, 1);
        assert!(
            run(Method::Load, &[Variant::Int16(1)], "AUTO").is_err(),
            "not while a program runs"
        );
    }
}
