//! A built PLC's run, from its first cycle to its summary: in virtual time as fast as the CPU
//! goes, or in real time on the cyclic thread while a tokio runtime serves the operator's screen
//! and OPC UA from one frame feed, watches the terminating signals, draws the status line and
//! talks to a service manager. The command line's `run` gives its options here and reports what
//! comes back.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use tracing::{info, warn};

use super::{Built, Failure, ScenarioTimes, Setup};
use crate::runtime::config::TimeSourceKind;
use crate::runtime::plc::Plc;
use crate::runtime::run::{self, RealTimeOptions};
use crate::runtime::status;
use crate::runtime::summary::Summary;

/// What a run is asked for beyond its build.
#[derive(Debug, Default)]
pub struct RunRequest {
    /// Virtual time: as fast as the CPU allows, for `duration_s` of simulated time — or, with
    /// `pace`, paced.
    pub virtual_time: bool,
    /// A simulation paced at this many times real time (with `virtual_time`): served as a
    /// real-time run is (the screen, OPC UA, the status line), until a signal or `duration_s`
    /// of simulated time.
    pub pace: Option<f64>,
    /// How long it runs (s; of simulated time in virtual time); `None`: until a signal.
    pub duration_s: Option<f64>,
    /// The time source in place of the configuration's.
    pub time_source: Option<TimeSourceKind>,
    /// The operator's screen, where it is served (real time, or a paced simulation).
    pub screen: Option<crate::services::hmi::HmiOptions>,
    /// The OPC UA server (real time, or a paced simulation).
    pub opcua: Option<OpcUaRequest>,
    /// The trace to record.
    pub trace: Option<PathBuf>,
}

/// The OPC UA server a run is asked for.
#[derive(Debug)]
pub struct OpcUaRequest {
    /// Its endpoint, security and users.
    pub options: crate::services::opcua::OpcUaOptions,
    /// The next ports tried when the endpoint's is taken (the default endpoint only).
    pub next_ports: u16,
    /// Asked for by name (a server that cannot start ends the run), not the default.
    pub explicit: bool,
}

/// A run that ended: its summary, and what failed that is reported after it (a trace that could
/// not be written, a bus that never came up).
pub struct Ran {
    /// The run's summary.
    pub summary: Summary,
    /// Its failure, if any: the exit code and message the command line gives.
    pub failure: Result<(), Failure>,
}

/// Runs `built` as `request` asks, to its end: a signal, its duration, or a failure of the cyclic
/// thread. A screen or OPC UA server that cannot be had ends the run before its first cycle.
pub fn run(built: Built, request: RunRequest) -> Result<Ran, Failure> {
    let Built {
        setup,
        mut plc,
        joystick,
        library,
        refused,
        hmi,
        scenario,
    } = built;
    let loaded = &setup.loaded;
    // Each reason starts with the file's name.
    for (_, why) in &refused {
        info!("screen: not offered: {}", why.lines().next().unwrap_or_default());
    }
    if let Some(path) = &request.trace {
        let digest = setup.digest()?;
        let recorder = crate::services::trace::record::Recorder::create_for(
            path,
            &plc,
            &digest,
            library.as_ref(),
            setup.tools.as_ref().map(|t| crate::services::trace::TraceProgram {
                file: t.file.clone(),
                text: t.text.clone(),
            }),
            setup.persistent.map(Into::into),
        )
        .map_err(|e| Failure::run(format!("{}: cannot create the trace: {e}", path.display())))?;
        plc.set_recorder(Box::new(recorder));
    }
    info!("configuration: {}; bus: {}", loaded.origin, plc.bus_name());
    if plc.app_program().is_some_and(|p| p.starts_with("selftest.")) {
        warn!("running the runtime's built-in self-test programs, not a machine's application");
    }
    let duration_s = duration(request.duration_s, scenario);
    let pace = request.pace.filter(|_| request.virtual_time);
    // The tool table as the screen and the programs' G10 L1 change it: written back by a
    // machine's run, kept for the run by a simulation.
    let tools = setup.tools.as_ref().map(|t| {
        Arc::new(crate::runtime::tool_table::ToolTableKeeper::new(
            t.file.clone(),
            t.table.clone(),
            !request.virtual_time,
        ))
    });
    if request.virtual_time && pace.is_none() {
        let duration = duration_s.ok_or_else(|| {
            Failure::usage(
                "--virtual needs --duration (or --pace X: a simulation paced at X times real time runs until stopped)",
            )
        })?;
        return Ok(run_virtual(plc, &loaded.origin, library.as_ref(), tools, duration));
    }
    let timing = &loaded.config.timing;
    let options = match pace {
        // A simulation: no real-time priority, no locked memory (the cycles are never late in
        // virtual time), waits on the plain sleep.
        Some(_) => RealTimeOptions {
            source: TimeSourceKind::Nanosleep,
            realtime_priority: 0,
            lock_memory: false,
            spin_ns: 0,
            duration_ns: duration_s.map(|d| (d * 1e9) as u64),
            pace,
        },
        None => RealTimeOptions {
            source: request.time_source.unwrap_or(timing.source),
            realtime_priority: timing.realtime_priority,
            lock_memory: timing.lock_memory,
            spin_ns: u64::from(timing.spin_us) * 1000,
            duration_ns: duration_s.map(|d| (d * 1e9) as u64),
            pace: None,
        },
    };
    match pace {
        Some(pace) => info!(
            "simulation: virtual time paced at {pace}x real time (the machine is simulated; nothing moves); Ctrl-C stops"
        ),
        None => info!(
            "real time, time source {}; Ctrl-C stops",
            options.source.resolve().name()
        ),
    }
    let probe = match joystick {
        Some(j) => {
            let super::Joystick {
                spec,
                feed,
                probe,
                stop,
            } = j;
            crate::services::io::hid::spawn_reader(spec, loaded.config.joystick.clone(), feed, Arc::clone(&stop))
                .map_err(|e| Failure::run(format!("cannot start the joystick reader: {e}")))?;
            Some((probe, stop))
        }
        None => None,
    };
    let program_files: Vec<String> = library
        .as_ref()
        .map_or(&[][..], |l| &l.jobs)
        .iter()
        .map(|j| j.file.clone())
        .collect();
    let opcua = match (request.opcua, &hmi) {
        (Some(asked), Some(sink)) => Some(OpcUa {
            info: space_info(&plc, &setup, program_files),
            asked,
            sink: sink.clone(),
            tools: tools.clone(),
            library: library.clone(),
        }),
        _ => None,
    };
    let screen = match (request.screen, hmi) {
        (Some(options), Some(sink)) => Some(Screen {
            info: screen_info(&plc, &setup, library.as_ref(), refused, pace, tools.clone()),
            options,
            sink,
        }),
        _ => None,
    };
    let mut outcome = run_realtime(plc, options, screen, opcua, library.as_ref(), tools)?;
    if let Some((probe, stop)) = probe {
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(l) = probe.summary(outcome.epoch_ns) {
            info!(
                "joystick: {} reports taken into the process image, {:.1} ms mean, {:.1} ms max after the reader handed them over",
                l.count, l.mean_ms, l.max_ms
            );
        }
    }
    let failure = finish_trace(&mut outcome.plc).and_then(|()| bus_came_up(&outcome.plc));
    let mode = if pace.is_some() { "paced" } else { "real-time" };
    let mut summary = Summary::collect(&outcome.plc, mode, &loaded.origin, outcome.elapsed_ns)
        .with_program(&outcome.plc, library.as_ref());
    summary.time_source = Some(outcome.source.name());
    summary.realtime_priority = Some(outcome.realtime_priority);
    Ok(Ran { summary, failure })
}

/// How long the run lasts (s): `--duration`, else the scenario's `duration_s`, else until a
/// signal (said at the start, with the scenario's last event).
fn duration(asked: Option<f64>, scenario: Option<ScenarioTimes>) -> Option<f64> {
    match (asked, scenario) {
        (Some(d), _) => Some(d),
        (
            None,
            Some(ScenarioTimes {
                duration_s: Some(d), ..
            }),
        ) => {
            info!("the scenario lasts {d} s: the run ends then (--duration overrides)");
            Some(d)
        }
        (None, Some(times)) => {
            info!(
                "the scenario's last event is at {} s; the run goes on after it until stopped (--duration S, or \"duration_s\" in the scenario, ends it)",
                times.last_event_s
            );
            None
        }
        (None, None) => None,
    }
}

/// Runs `plc` in virtual time for `duration` s of simulated time.
fn run_virtual(
    mut plc: Plc,
    origin: &str,
    library: Option<&pkm_api::library::NcLibrary>,
    tools: Option<Arc<crate::runtime::tool_table::ToolTableKeeper>>,
    duration: f64,
) -> Ran {
    // The programs' message comments to the log as the run reaches them, and their tool table
    // entries (G10 L1) kept for the run.
    let mut messages = crate::runtime::messages::MessageWatch::new(plc.vars(), library);
    let report = run::run_virtual_observed(&mut plc, (duration * 1e9) as u64, &mut |plc, t| {
        if let Some(m) = &mut messages {
            let reached = m.log(plc.global_image(), t);
            if let Some(keeper) = &tools {
                crate::runtime::tool_table::write_back(keeper, &reached);
            }
        }
    });
    info!(
        "virtual time: {:.3} s simulated in {:.3} s wall-clock ({:.0}x)",
        duration,
        report.wall.as_secs_f64(),
        duration / report.wall.as_secs_f64().max(1e-9)
    );
    let failure = finish_trace(&mut plc);
    let summary = Summary::collect(&plc, "virtual", origin, report.simulated_ns).with_program(&plc, library);
    Ran { summary, failure }
}

/// The operator's screen of a real-time run: where, what it shows at connection, where its
/// commands go.
struct Screen {
    options: crate::services::hmi::HmiOptions,
    info: crate::services::hmi::server::HmiInfo,
    sink: crate::services::hmi::commands::CommandSink,
}

/// The OPC UA server of a real-time run: as asked, what it shows, where its commands go.
struct OpcUa {
    asked: OpcUaRequest,
    info: crate::services::opcua::space::SpaceInfo,
    sink: crate::services::hmi::commands::CommandSink,
    /// The tool table, for the machine tool's `Equipment/Tools`.
    tools: Option<Arc<crate::runtime::tool_table::ToolTableKeeper>>,
    /// The programs as planned, for the machine tool's tool change prognosis.
    library: Option<pkm_api::library::NcLibrary>,
}

/// What the screen shows at connection.
fn screen_info(
    plc: &Plc,
    setup: &Setup,
    library: Option<&pkm_api::library::NcLibrary>,
    refused: Vec<(String, String)>,
    pace: Option<f64>,
    tools: Option<Arc<crate::runtime::tool_table::ToolTableKeeper>>,
) -> crate::services::hmi::server::HmiInfo {
    let motion = setup.machine.and_then(|m| m.motion(&setup.loaded.json).ok());
    crate::services::hmi::server::HmiInfo {
        simulation: pace,
        machine: setup.machine.map_or("runtime".to_string(), |m| m.name().to_string()),
        config: setup.origin().to_string(),
        variables: plc
            .vars()
            .vars()
            .iter()
            .map(|v| (v.name.clone(), v.ty.to_string()))
            .collect(),
        programs: library
            .map_or(&[][..], |l| &l.jobs)
            .iter()
            .map(|j| crate::services::hmi::server::ScreenProgram {
                file: j.file.clone(),
                text: j.text.clone(),
                path: crate::services::hmi::server::preview(j.trajectory.as_ref()),
                planned_s: j.trajectory.duration_s(),
            })
            .collect(),
        refused,
        mechanism: crate::services::hmi::mechanism::Mechanism::of(setup, plc),
        axes: motion
            .as_ref()
            .map(|m| m.axes.iter().map(|a| a.to_string()).collect())
            .unwrap_or_default(),
        joints: motion
            .map(|m| m.joint_vars.iter().map(|v| v.to_string()).collect())
            .unwrap_or_default(),
        jobs: library
            .zip(crate::compose::screen_job::StandingPose::of(setup, plc))
            .map(|(l, standing)| {
                let loaded = plc
                    .vars()
                    .index_of(pkm_api::trajectory::vars::NC_PROGRAM.name())
                    .map(usize::from);
                let n = setup
                    .machine
                    .and_then(|m| m.motion(&setup.loaded.json).ok())
                    .map_or(0, |m| m.axes.len());
                crate::services::hmi::jobs::JobDesk::new(
                    setup.clone(),
                    l.clone(),
                    standing,
                    loaded,
                    setup.persistent(n),
                    setup.keeper(n),
                )
                .with_tools(tools)
            }),
        tools: setup
            .tools
            .as_ref()
            .map(|t| t.table.tools.iter().map(|t| (t.number, t.comment.clone())).collect())
            .unwrap_or_default(),
        library: library.cloned(),
    }
}

/// A server's listener: on `addr`, or — when its port is taken (a second PLC on this computer)
/// — on the next free one of the `next_ports` after it or else any free port, said in a warning
/// (`what` names the server). When none can be had, the usage error that ends the run before it
/// starts, with the first error and what to do `instead`.
async fn listen(
    addr: std::net::SocketAddr,
    next_ports: u16,
    what: &str,
    instead: &str,
) -> Result<tokio::net::TcpListener, Failure> {
    let taken = match tokio::net::TcpListener::bind(addr).await {
        Ok(listener) => return Ok(listener),
        Err(e) => e,
    };
    if taken.kind() == std::io::ErrorKind::AddrInUse && next_ports > 0 {
        // The next ports, then any free one (the log says which).
        let next = (1..=next_ports).map(|k| addr.port().saturating_add(k));
        for port in next.chain([0]) {
            let mut at = addr;
            at.set_port(port);
            if let Ok(listener) = tokio::net::TcpListener::bind(at).await {
                warn!(
                    "{what}: {addr} is taken (another pkm-plc?): serving on {} instead",
                    listener.local_addr().map_or(at, |a| a)
                );
                return Ok(listener);
            }
        }
    }
    let busy = if taken.kind() == std::io::ErrorKind::AddrInUse {
        " (another pkm-plc, or another server, has it)"
    } else {
        ""
    };
    Err(Failure::usage(format!(
        "{what}: cannot listen on {addr}: {taken}{busy}; {instead}"
    )))
}

/// Runs in real time on a tokio runtime that watches for the terminating signals (Ctrl-C,
/// SIGTERM, SIGHUP, …: [`crate::runtime::signals`]) and draws the status line, while the cyclic
/// thread does the work.
fn run_realtime(
    plc: Plc,
    options: RealTimeOptions,
    screen: Option<Screen>,
    opcua: Option<OpcUa>,
    library: Option<&pkm_api::library::NcLibrary>,
    tools: Option<Arc<crate::runtime::tool_table::ToolTableKeeper>>,
) -> Result<run::RealTimeOutcome, Failure> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| Failure::run(format!("cannot start the tokio runtime: {e}")))?;
    // The handlers before the first cycle: a signal from then on stops the run safely.
    let signals = {
        let _inside = runtime.enter();
        crate::runtime::signals::Terminating::register()
    };
    let _inside = runtime.enter();
    // The listeners first: an address that cannot be had ends the run before anything moves —
    // a page or a SCADA open on that port shows another PLC (a second one started by mistake),
    // so running on without the server would mislead.
    let screen = screen
        .map(|screen| {
            let (addr, next) = (screen.options.addr, screen.options.next_ports);
            let instead = "give another address with --hmi ADDR (port 0: any free one, logged), or run without a screen with --hmi none";
            runtime
                .block_on(listen(addr, next, "operator screen", instead))
                .map(|listener| (screen, listener))
        })
        .transpose()?;
    let opcua = opcua
        .map(|server| {
            let (addr, next) = (server.asked.options.addr, server.asked.next_ports);
            let instead = "give another endpoint with --opcua opc.tcp://HOST:PORT (port 0: any free one, logged), or run without OPC UA with --opcua none";
            runtime
                .block_on(listen(addr, next, "OPC UA", instead))
                .map(|listener| (server, listener))
        })
        .transpose()?;
    // Both are fed from one publication per main cycle, as is the log of the programs'
    // messages.
    let messages = crate::runtime::messages::MessageWatch::new(plc.vars(), library);
    let (publisher, feed) = if screen.is_some() || opcua.is_some() || messages.is_some() {
        let (publisher, reader) = crate::runtime::frame::frames(&plc);
        (Some(publisher), Some(crate::runtime::frame::FrameFeed::spawn(reader)))
    } else {
        (None, None)
    };
    if let (Some(mut watch), Some(feed)) = (messages, &feed) {
        let mut feed = feed.clone();
        tokio::spawn(async move {
            while let Some(frame) = feed.next().await {
                let reached = watch.log(&frame.image, frame.status.t_ns);
                // A program's G10 L1 written back to the tool table as the run reaches it, in
                // order (the file is written and flushed on a blocking thread).
                if let Some(keeper) = &tools
                    && reached
                        .iter()
                        .any(|m| m.kind == pkm_api::trajectory::NcMessageKind::ToolEntry)
                {
                    let keeper = Arc::clone(keeper);
                    let _ =
                        tokio::task::spawn_blocking(move || crate::runtime::tool_table::write_back(&keeper, &reached))
                            .await;
                }
            }
        });
    }
    if let (Some((screen, listener)), Some(feed)) = (screen, &feed) {
        serve_screen(screen, listener, feed.clone());
    }
    if let (Some((server, listener)), Some(feed)) = (opcua, &feed) {
        serve_opcua(
            server,
            listener,
            feed.clone(),
            plc.app_period_ns().unwrap_or(50_000_000),
        )?;
    }
    let run = run::start_realtime_with(plc, options, publisher).map_err(|e| Failure::run(e.to_string()))?;
    let outcome = runtime.block_on(supervise(run, signals, options.pace));
    // The run is over (its outputs are safe): the runtime is left without waiting for what it
    // still does — a screen job being planned on its blocking pool would hold its drop until
    // the plan ended, and the summary and the exit with it.
    drop(_inside);
    runtime.shutdown_background();
    outcome.map_err(|e| match e {
        // The station is not the I/O map's: a problem of the setup, as a bad configuration is.
        run::RunError::StationRefused(why) => Failure::usage(why),
        other => Failure::run(other.to_string()),
    })
}

/// Watches a real-time run (or a paced simulation, `pace`) from the tokio runtime until it ends: a terminating signal stops it
/// safely; the status line is drawn, the first complete round of cycles is logged (scripts and
/// tests wait for that line), and a service manager is told the run's state and fed its
/// watchdog while the cycles run.
async fn supervise(
    run: run::RealTimeRun,
    mut signals: crate::runtime::signals::Terminating,
    pace: Option<f64>,
) -> Result<run::RealTimeOutcome, run::RunError> {
    let stop = run.stop_flag();
    let snapshot = run.snapshot();
    let heartbeat = run.heartbeat();
    // A service manager's notifications (systemd, Type=notify), when it asked for them.
    let mut notifier = crate::runtime::service::Notifier::from_env();
    let status_task = status::wanted().then(|| status::spawn(Arc::clone(&snapshot), Duration::from_millis(250)));
    // Said once every class has run a cycle: scripts and tests wait for this line.
    let mut ready = false;
    let mut poll = tokio::time::interval(Duration::from_millis(20));
    loop {
        tokio::select! {
            name = signals.recv() => {
                info!("{name}: stopping after the current cycle, outputs to safe values");
                stop.store(true, std::sync::atomic::Ordering::Relaxed);
                if let Some(n) = &mut notifier {
                    n.stopping();
                }
                break;
            }
            _ = poll.tick() => {
                if run.is_finished() {
                    break;
                }
                let (cycled, running, state) = match snapshot.lock() {
                    Ok(s) => {
                        let cycled = s.classes.iter().all(|c| c.cycles > 0);
                        let state = if s.reason.is_empty() {
                            s.state.clone()
                        } else {
                            format!("{}: {}", s.state, s.reason)
                        };
                        (cycled, cycled && !s.bus_fault, state)
                    }
                    Err(_) => (false, false, String::new()),
                };
                if !ready && cycled {
                    ready = true;
                    match pace {
                        Some(pace) => info!("running the simulation at {pace}x real time; Ctrl-C, SIGTERM or SIGHUP stops it safely"),
                        None => info!("running in real time; Ctrl-C, SIGTERM or SIGHUP stops it safely"),
                    }
                }
                if let Some(n) = &mut notifier {
                    n.tick(running, heartbeat.load(std::sync::atomic::Ordering::Relaxed), &state);
                }
            }
        }
    }
    // The cyclic thread ends within one wait (at most the shortest cycle time) of the stop.
    while !run.is_finished() {
        poll.tick().await;
    }
    if let Some(task) = status_task {
        task.abort();
    }
    status::finish();
    run.join()
}

/// Serves the operator's screen on `listener` (inside the tokio runtime).
fn serve_screen(screen: Screen, listener: tokio::net::TcpListener, feed: crate::runtime::frame::FrameFeed) {
    let Screen { options, info, sink } = screen;
    let server_options = crate::services::hmi::server::ServerOptions {
        access: crate::services::hmi::access::Access {
            token: options.token.clone(),
            allowed_origins: options.allowed_origins.clone(),
        },
        max_clients: options.max_clients,
    };
    let router = crate::services::hmi::server::router(info, feed, sink, server_options);
    let at = listener.local_addr().map_or(options.addr, |a| a);
    info!(
        "operator screen at http://{at}/{}",
        if options.token.is_some() {
            " (commands need the token: ?token=…)"
        } else {
            ""
        }
    );
    // Connections: the clients', and room for pages and assets loading.
    let listener = crate::services::hmi::listener::Bounded::new(listener, options.max_clients + 8);
    tokio::spawn(async move {
        let service = router.into_make_service_with_connect_info::<crate::services::hmi::listener::Peer>();
        if let Err(e) = axum::serve(listener, service).await {
            warn!("operator screen: {e}");
        }
    });
}

/// Starts the OPC UA server behind `listener` (inside the tokio runtime). One asked for with
/// `--opcua` that cannot start ends the run before it starts; the default's failure is a warning.
fn serve_opcua(
    server: OpcUa,
    listener: tokio::net::TcpListener,
    feed: crate::runtime::frame::FrameFeed,
    main_period_ns: u64,
) -> Result<(), Failure> {
    let OpcUa {
        asked,
        info,
        sink,
        tools,
        library,
    } = server;
    let OpcUaRequest { options, explicit, .. } = asked;
    let planned = crate::services::opcua::server::Planned { tools, library };
    match crate::services::opcua::server::start(&options, listener, info, feed, sink, main_period_ns, planned) {
        Ok(url) => info!(
            "OPC UA server at {url} ({})",
            match &options.users {
                Some(u) => format!(
                    "anonymous sessions read; the {} users of {} also command",
                    u.users.len(),
                    u.origin.display()
                ),
                None => "read-only: commands need --opcua-users".to_string(),
            }
        ),
        // Asked for: nothing runs without it. The default: the machine runs, said once.
        Err(e) if explicit => return Err(Failure::usage(format!("OPC UA: cannot start the server: {e}"))),
        Err(e) => warn!(
            "OPC UA: not served: {e}; give a certificate store with --opcua-pki DIR, or turn OPC UA off with --opcua none"
        ),
    }
    Ok(())
}

/// A run over a Modbus link that never made one exchange failed (exit 1), with why: the machine
/// was never under control.
fn bus_came_up(plc: &Plc) -> Result<(), Failure> {
    let Some(link) = plc
        .bus()
        .as_any()
        .downcast_ref::<crate::services::io::modbus::ModbusBus>()
    else {
        return Ok(());
    };
    if link.stats().exchanges.load(std::sync::atomic::Ordering::Relaxed) > 0 {
        return Ok(());
    }
    let mut cause = String::new();
    if !plc.bus().write_fault_cause(&mut cause) {
        cause = "no exchange succeeded".into();
    }
    Err(Failure::run(format!(
        "{}: the bus never came up: {cause}",
        plc.bus_name()
    )))
}

/// Flushes and closes the trace, if one is being recorded; a write error is the run's failure,
/// reported after the summary.
fn finish_trace(plc: &mut Plc) -> Result<(), Failure> {
    match plc.take_recorder().map(|r| r.finish()) {
        Some(Ok(message)) => {
            info!("{message}");
            Ok(())
        }
        Some(Err(e)) => Err(Failure::run(e.to_string())),
        None => Ok(()),
    }
}

/// What the address space shows of `plc` built from `setup`.
fn space_info(plc: &Plc, setup: &Setup, programs: Vec<String>) -> crate::services::opcua::space::SpaceInfo {
    let classes: Vec<(String, u64)> = plc.classes().map(|c| (c.name.to_string(), c.period_ns)).collect();
    let names: Vec<&str> = classes.iter().map(|(n, _)| n.as_str()).collect();
    // The machine's limits bound some variables' ranges (a configuration the machine refuses
    // has none: the run would not have started).
    let motion = setup.machine.and_then(|m| m.motion(&setup.loaded.json).ok());
    let variables = plc
        .vars()
        .vars()
        .iter()
        .map(|v| {
            let class = match &v.writer {
                Some(crate::image::Writer::Program { class, .. } | crate::image::Writer::Bus { class, .. }) => *class,
                None => v.readers.first().map_or(0, |r| r.class),
            };
            let writer = match &v.writer {
                Some(crate::image::Writer::Program { program, .. }) => format!("program {program}"),
                Some(crate::image::Writer::Bus { class, .. }) => format!(
                    "the bus (latched by class {})",
                    names.get(*class).copied().unwrap_or("?")
                ),
                None => "nobody (it keeps its default)".to_string(),
            };
            crate::services::opcua::space::VarNode {
                range: crate::services::opcua::ranges::of(&v.name, motion.as_ref()),
                name: v.name.clone(),
                ty: v.ty,
                class,
                writer,
            }
        })
        .collect();
    let nameplate = setup.machine.map(|m| {
        let nameplate = crate::services::opcua::companion::Nameplate::new(
            &setup.loaded.config.identification,
            m.name(),
            m.summary(),
            &crate::services::opcua::server::host_name(),
        );
        if !nameplate.missing.is_empty() {
            tracing::info!(
                "OPC UA: the machine's nameplate shows \"{}\" for {} (not in {}: identification)",
                crate::services::opcua::companion::UNKNOWN,
                nameplate.missing.join(", "),
                setup.origin()
            );
        }
        nameplate
    });
    crate::services::opcua::space::SpaceInfo {
        machine: setup.machine.map_or("runtime".to_string(), |m| m.name().to_string()),
        config: setup.origin().to_string(),
        classes,
        variables,
        programs,
        nameplate,
    }
}
