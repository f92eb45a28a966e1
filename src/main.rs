//! The `pkm-plc` command line.
//!
//! Exit codes: 0 success; 1 the run failed (timer, thread, file output); 2 usage or configuration
//! error (nothing was started).

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

use clap::{Args, Parser, Subcommand};
use tracing::{info, warn};
use tracing_subscriber::EnvFilter;
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;

use cli::bench::{self, BenchOptions};
use cli::enums::{Exchange, TimeSource};
use pkm_plc::compose::{self, Built, BusChoice, JoystickChoice, Options, Setup};
use pkm_plc::runtime::config::{self, ConfigError, LoadedConfig, TimeSourceKind};
use pkm_plc::runtime::plc::Plc;
use pkm_plc::runtime::run::{self, RealTimeOptions};
use pkm_plc::runtime::status;
use pkm_plc::runtime::summary::Summary;
use pkm_plc::services::io::hid::JoystickSpec;
use pkm_plc::services::io::modbus::ExchangeMode;

mod cli;

/// A soft-PLC for parallel-kinematic machine models.
#[derive(Parser, Debug)]
#[command(name = "pkm-plc", version, about, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run the soft-PLC (real time until Ctrl-C, or virtual time for a given duration).
    Run(Box<RunArgs>),
    /// Validate a configuration without running anything.
    Check(ConfigArg),
    /// Measure the time sources side by side (cycle start lateness of a 10 ms class).
    Bench(BenchArgs),
    /// Kinematics of a machine model: fk, ik, workspace, bench, convergence.
    Kin(cli::kin::KinArgs),
    /// NC programs: check one against the configured machine.
    Nc(cli::nc::NcArgs),
    /// Replay a trace: feed its inputs to the programs, compare every output and state.
    Replay(ReplayArgs),
    /// Look into a trace: VCD for GTKWave, SVG time plots, the tool path of a run with a program,
    /// the summary a reviewer diffs.
    Trace(TraceArgs),
    /// Print the Modbus register map that the configuration's I/O map gives.
    Registers(ConfigArg),
    /// Serve the I/O map's modules as a Modbus TCP or RTU slave, backed by the simulated machine.
    IoSim(IoSimArgs),
    /// Measure the Modbus RTU exchange at a baud rate over an emulated RS-485 line (driver and
    /// io-sim in this process, joined by pseudo-terminals paced at the baud rate).
    LinkBench(LinkBenchArgs),
    /// The real station: `station scan tcp:HOST[:PORT]` lists an X20BC0087's identity,
    /// network settings, modules, watchdog and error bits (read-only).
    Station(StationArgs),
}

#[derive(Args, Debug)]
struct StationArgs {
    #[command(subcommand)]
    op: StationOp,
}

#[derive(Subcommand, Debug)]
enum StationOp {
    /// Read an X20BC0087's identity, network settings, module table, watchdog and error bits;
    /// it writes nothing to the station.
    Scan {
        /// The bus controller: `tcp:HOST[:PORT]` (port 502 when not given).
        address: String,
        /// Also write an I/O map skeleton for the modules found to FILE (which must not exist).
        #[arg(long, value_name = "FILE")]
        write_map: Option<PathBuf>,
        /// How long each request may take (ms).
        #[arg(long, value_name = "MS", default_value_t = 1000, value_parser = clap::value_parser!(u64).range(1..=60_000))]
        timeout_ms: u64,
    },
}

#[derive(Args, Debug)]
struct LinkBenchArgs {
    /// The line's baud rate.
    #[arg(long, default_value_t = 115_200, value_parser = clap::value_parser!(u32).range(1200..=4_000_000))]
    baud: u32,
    /// Seconds per exchange mode.
    #[arg(long, default_value_t = 10.0, value_parser = parse_seconds)]
    seconds: f64,
    /// The exchange modes to measure.
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [Exchange::Tables, Exchange::Image])]
    exchange: Vec<Exchange>,
    #[command(flatten)]
    config: ConfigArg,
    /// Also write the rows as JSON to FILE.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
}

#[derive(Args, Debug)]
struct IoSimArgs {
    /// Serve Modbus TCP on this address (port 0: any free port; the address is printed first).
    #[arg(
        long,
        value_name = "ADDR",
        required_unless_present = "serial",
        conflicts_with = "serial"
    )]
    tcp: Option<std::net::SocketAddr>,
    /// Serve Modbus RTU on this serial device, `PATH[@BAUD]` (115 200 baud by default).
    #[arg(long, value_name = "PATH[@BAUD]", value_parser = parse_serial)]
    serial: Option<(String, u32)>,
    #[command(flatten)]
    config: ConfigArg,
    /// A scenario for the simulated machine (panel inputs and faults).
    #[arg(long, value_name = "FILE")]
    scenario: Option<PathBuf>,
    /// Output watchdog: every output goes to its safe value (zero) when no write request arrives
    /// for this long, as a real bus coupler's outputs do when the controller dies; 0 turns it off.
    /// An X20BC0087 station (over TCP) starts with it as its stored setting, which clients change.
    #[arg(long, value_name = "MS", default_value_t = 100)]
    watchdog_ms: u64,
    /// An X20BC0087 station's node number (its rotary switches), which it reports.
    #[arg(long, value_name = "N", default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=255))]
    node: u16,
    /// Modbus TCP clients served at once; more are closed as they connect.
    #[arg(long, value_name = "N", default_value_t = 8, value_parser = clap::value_parser!(u16).range(1..))]
    max_connections: u16,
    /// A Modbus TCP client that sends no request for this long is disconnected (seconds).
    #[arg(long, value_name = "S", default_value_t = 60, value_parser = clap::value_parser!(u64).range(1..))]
    idle_timeout_s: u64,
}

#[derive(Args, Debug)]
struct TraceArgs {
    #[command(subcommand)]
    op: TraceOp,
}

#[derive(Subcommand, Debug)]
enum TraceOp {
    /// Convert to VCD (timescale 1 µs), every variable plus the main state and reason.
    Vcd {
        /// The trace.
        trace: PathBuf,
        /// The VCD file to write.
        out: PathBuf,
    },
    /// Print the state transitions and the main class's outputs sampled every few seconds: the
    /// text a reviewer diffs (the golden traces keep one beside them, `NAME.expected`).
    Summary {
        /// The trace.
        trace: PathBuf,
        /// Seconds between samples of the outputs.
        #[arg(long, default_value_t = 5.0, value_parser = parse_seconds)]
        every: f64,
    },
    /// Plot variables and the main state against time (SVG).
    Plot {
        /// The trace.
        trace: PathBuf,
        /// The SVG file to write.
        out: PathBuf,
        /// The variables to plot [default: the positions the trace has: every machine's
        /// JOINTn_POSITION and TOOL_X …].
        #[arg(long, value_delimiter = ',')]
        vars: Vec<String>,
    },
    /// Draw the programmed against the actual tool path of a run with a program (SVG), and its
    /// contour error against time.
    Path {
        /// The trace (of `run --program FILE --trace …`).
        trace: PathBuf,
        /// The SVG file to write.
        out: PathBuf,
        /// Draw the actual path's deviation from the programmed one this many times as large.
        #[arg(long, default_value_t = 1.0, value_parser = parse_magnification)]
        magnify: f64,
    },
}

/// A magnification: at least 1, at most 100 000.
fn parse_magnification(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if (1.0..=100_000.0).contains(&v) => Ok(v),
        _ => Err(format!("must be a number from 1 to 100000, got {s}")),
    }
}

#[derive(Args, Debug)]
struct ReplayArgs {
    /// The trace (JSON Lines, from `run --trace`).
    #[arg(value_name = "TRACE")]
    trace: PathBuf,
    #[command(flatten)]
    config: ConfigArg,
    /// Replay even if the trace was recorded with another configuration or I/O map.
    #[arg(long)]
    force: bool,
}

#[derive(Args, Debug)]
pub(crate) struct ConfigArg {
    /// Configuration file [default: ./config.json if present, else the built-in one].
    #[arg(long, value_name = "FILE")]
    pub(crate) config: Option<PathBuf>,
    /// A machine's own configuration: short for `--config machines/NAME.json` (the TRIJOINT's is
    /// config.json); the built-in copy when the file is not there.
    #[arg(long, value_name = "NAME", conflicts_with = "config",
          value_parser = clap::builder::PossibleValuesParser::new(pkm_plc::compose::machines::BUILTIN.iter().map(|m| m.name())))]
    pub(crate) machine: Option<String>,
}

#[derive(Args, Debug)]
struct RunArgs {
    #[command(flatten)]
    config: ConfigArg,
    /// Run in virtual time: as fast as the CPU allows, deterministic. Needs --duration.
    #[arg(long = "virtual", requires = "duration")]
    virtual_time: bool,
    /// Stop after this many seconds (of simulated time with --virtual).
    #[arg(long, value_name = "SECONDS", value_parser = parse_seconds)]
    duration: Option<f64>,
    /// Write a JSON summary (cycle statistics, final state) to FILE at exit.
    #[arg(long, value_name = "FILE")]
    summary: Option<PathBuf>,
    /// The field bus: `sim` (the configured machine's simulated plant behind its I/O map),
    /// `tcp:HOST:PORT` (a Modbus TCP station serving the I/O map's register map),
    /// `serial:PATH[@BAUD]` (the same over Modbus RTU, 115 200 baud by default), or `none`.
    #[arg(long, default_value = "sim", value_parser = parse_bus)]
    bus: BusChoice,
    /// How a Modbus bus exchanges the I/O each time: `tables` (four requests on the standard
    /// tables, any server), `image` (one read/write-multiple-registers request on the packed
    /// process image, as io-sim serves it), or `auto` (image on serial, tables on TCP).
    #[arg(long, value_enum, default_value_t = Exchange::Auto)]
    exchange: Exchange,
    /// A Modbus bus faults when its newest complete input image is older than this (ms), however
    /// the exchanges fail: slow responses that never time out count too.
    #[arg(long, value_name = "MS", default_value_t = 50, value_parser = clap::value_parser!(u64).range(1..))]
    max_input_age_ms: u64,
    /// A Modbus bus faults when its exchanges take longer than this (the median of the last
    /// five, ms): the drive regulators were tuned for inputs this fresh, and oscillate on a
    /// slower link. Raise it only after checking the regulators on that link.
    #[arg(long, value_name = "MS", default_value_t = 8, value_parser = clap::value_parser!(u64).range(1..=1000))]
    max_exchange_ms: u64,
    /// A scenario for the simulated machine: timed operator actions and faults (JSON).
    #[arg(long, value_name = "FILE")]
    scenario: Option<PathBuf>,
    /// The HID joystick: an input device (`/dev/input/eventN`), a FIFO or capture file of raw
    /// `struct input_event` records, `auto` (the first joystick or gamepad; none: panel
    /// buttons only), or `none` (the bus's own joystick channels, e.g. the simulated machine's).
    #[arg(long, value_name = "DEVICE|FILE|auto|none", default_value = "auto")]
    joystick: JoystickSpec,
    /// Record every class cycle (inputs, outputs, main state) to FILE (JSON Lines).
    #[arg(long, value_name = "FILE")]
    trace: Option<PathBuf>,
    /// An NC program (G-code) to run: checked and planned at start (refused with exit code 2
    /// if it cannot run), started once the machine is READY after referencing (state AUTO).
    #[arg(long, value_name = "FILE")]
    program: Option<PathBuf>,
    /// The programs (`*.ngc`) the operator may load from the screen, each checked and planned
    /// at start (those that cannot run on the machine are listed with why), or `none`. Real
    /// time with a screen only; default `programs` (if that directory exists).
    #[arg(long, value_name = "DIR|none")]
    programs: Option<PathBuf>,
    /// The operator's screen: `ADDR` (host:port) to serve it at, or `none`. Real time only;
    /// default 127.0.0.1:8080, or the environment's PKM_PLC_HMI (another address than loopback
    /// needs --hmi-token).
    #[arg(long, value_name = "ADDR|none", value_parser = parse_hmi)]
    hmi: Option<HmiAddr>,
    /// The screen's commands (STOP, jog, program) need this token; without it a page watches.
    #[arg(long, value_name = "TOKEN", conflicts_with = "hmi_token_file")]
    hmi_token: Option<String>,
    /// As --hmi-token, the token read from FILE (its first line).
    #[arg(long, value_name = "FILE")]
    hmi_token_file: Option<PathBuf>,
    /// Another origin (`scheme://host[:port]`) whose pages may open the screen's WebSocket, and
    /// whose host the screen answers to (a reverse proxy's, say); repeatable. The screen's own
    /// page is always allowed.
    #[arg(long, value_name = "ORIGIN")]
    hmi_allow_origin: Vec<String>,
    /// The most clients the screen serves at once.
    #[arg(long, value_name = "N", default_value_t = pkm_plc::services::hmi::DEFAULT_MAX_CLIENTS)]
    hmi_max_clients: usize,
    /// The OPC UA server: `opc.tcp://HOST:PORT` to serve it at, or `none`. Real time only;
    /// default opc.tcp://127.0.0.1:4840 (another address than loopback needs --opcua-users).
    #[arg(long, value_name = "URL|none", env = "PKM_PLC_OPCUA")]
    opcua: Option<String>,
    /// The users who may command over OPC UA (a JSON file of names with a password or a
    /// certificate); without it the server is read-only.
    #[arg(long, value_name = "FILE")]
    opcua_users: Option<PathBuf>,
    /// The OPC UA server's certificate store: its certificate and key (made on first use) and
    /// the clients' trusted/ and rejected/ certificates. Default
    /// $XDG_DATA_HOME/pkm-plc/opcua-pki (~/.local/share/pkm-plc/opcua-pki).
    #[arg(long, value_name = "DIR")]
    opcua_pki: Option<PathBuf>,
    /// The most OPC UA sessions at once.
    #[arg(long, value_name = "N", default_value_t = pkm_plc::services::opcua::DEFAULT_MAX_SESSIONS)]
    opcua_max_sessions: usize,
    /// Override the configured time source (real time only).
    #[arg(long, value_enum, value_name = "SOURCE", conflicts_with = "virtual_time")]
    time_source: Option<TimeSource>,
}

#[derive(Args, Debug)]
struct BenchArgs {
    /// Seconds per measured row.
    #[arg(long, default_value_t = 30.0, value_parser = parse_seconds)]
    seconds: f64,
    /// Cycle time of the measured task class (µs).
    #[arg(long, default_value_t = 10_000)]
    cycle_us: u32,
    /// The time sources to measure.
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [TimeSource::Tokio, TimeSource::Timerfd, TimeSource::Nanosleep])]
    sources: Vec<TimeSource>,
    /// SCHED_FIFO priority for the real-time rows (0 skips them).
    #[arg(long, default_value_t = 80)]
    realtime_priority: u8,
    /// Also measure each source with this spin margin (µs) before each release (0: skip).
    #[arg(long, default_value_t = 0)]
    spin_us: u32,
    /// Also write the rows as JSON to FILE.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
}

/// Where the operator's screen is served.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum HmiAddr {
    /// Not at all.
    Off,
    /// At this address.
    At(std::net::SocketAddr),
}

fn parse_hmi(s: &str) -> Result<HmiAddr, String> {
    use std::net::ToSocketAddrs;
    if s == "none" {
        return Ok(HmiAddr::Off);
    }
    s.to_socket_addrs()
        .ok()
        .and_then(|mut a| a.next())
        .map(HmiAddr::At)
        .ok_or_else(|| format!("\"{s}\" is not HOST:PORT or none"))
}

/// `PATH[@BAUD]`, 115 200 baud by default.
fn parse_serial(s: &str) -> Result<(String, u32), String> {
    match s.rsplit_once('@') {
        Some((path, baud)) => baud
            .parse::<u32>()
            .ok()
            .filter(|b| *b > 0)
            .map(|b| (path.to_string(), b))
            .ok_or_else(|| format!("\"{baud}\" is not a baud rate")),
        None => Ok((s.to_string(), 115_200)),
    }
}

fn parse_bus(s: &str) -> Result<BusChoice, String> {
    use std::net::ToSocketAddrs;
    match s {
        "sim" => Ok(BusChoice::Sim),
        "none" => Ok(BusChoice::None),
        _ if s.starts_with("tcp:") => s[4..]
            .to_socket_addrs()
            .ok()
            .and_then(|mut a| a.next())
            .map(BusChoice::Tcp)
            .ok_or_else(|| format!("\"{}\" is not HOST:PORT", &s[4..])),
        _ if s.starts_with("serial:") => parse_serial(&s[7..]).map(|(p, b)| BusChoice::Serial(p, b)),
        _ => Err(format!(
            "\"{s}\" is not a bus: use sim, none, tcp:HOST:PORT or serial:PATH[@BAUD]"
        )),
    }
}

fn parse_seconds(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("\"{s}\" is not a number of seconds"))?;
    if v.is_finite() && v > 0.0 && v <= 1e7 {
        Ok(v)
    } else {
        Err(format!("must be more than 0 and at most 10000000 seconds, got {s}"))
    }
}

/// A failure with the exit code it means.
struct Failure {
    code: u8,
    message: String,
}

impl Failure {
    fn usage(message: impl Into<String>) -> Self {
        Failure {
            code: 2,
            message: message.into(),
        }
    }
    fn run(message: impl Into<String>) -> Self {
        Failure {
            code: 1,
            message: message.into(),
        }
    }
}

impl From<ConfigError> for Failure {
    fn from(e: ConfigError) -> Self {
        Failure::usage(e.to_string())
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    init_logging();
    let result = match cli.command {
        Command::Run(args) => cmd_run(*args),
        Command::Check(args) => cmd_check(args),
        Command::Bench(args) => cmd_bench(args),
        Command::Replay(args) => cmd_replay(args),
        Command::Trace(args) => cmd_trace(args),
        Command::Registers(args) => cmd_registers(args),
        Command::IoSim(args) => cmd_io_sim(args),
        Command::LinkBench(args) => cmd_link_bench(args),
        Command::Station(args) => cmd_station(args),
        Command::Kin(args) => cli::kin::run(args, load_config).map_err(|e| Failure {
            code: e.code,
            message: e.message,
        }),
        Command::Nc(args) => cli::nc::run(args, load_config).map_err(|e| Failure {
            code: e.code,
            message: e.message,
        }),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(f) => {
            status::finish();
            eprintln!("error: {}", f.message);
            ExitCode::from(f.code)
        }
    }
}

fn init_logging() {
    // The OPC UA crates say at info what the server's own line says once (endpoints, every
    // connection): their warnings and errors only, unless RUST_LOG asks for more.
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| {
        EnvFilter::new("info,opcua_server=warn,opcua_core=warn,opcua_crypto=warn,opcua_types=warn,opcua_nodes=warn")
    });
    // Every line, the libraries' too, within the log's budget: a peer's flood cannot fill the
    // disk (pkm_plc::runtime::log_limit).
    let budget = pkm_plc::runtime::log_limit::LogBudget::new();
    // Under systemd the journal keeps the time and reads each line's level from its prefix.
    let journal = pkm_plc::runtime::service::logging_to_journal().then(|| {
        tracing_subscriber::fmt::layer()
            .with_writer(status::LogWriter)
            .with_ansi(false)
            .event_format(pkm_plc::runtime::service::JournalFormat)
    });
    let format = (!pkm_plc::runtime::service::logging_to_journal()).then(|| {
        tracing_subscriber::fmt::layer()
            .with_writer(status::LogWriter)
            .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
            .with_target(false)
    });
    tracing_subscriber::registry()
        .with(filter)
        .with(pkm_plc::runtime::log_limit::BudgetLayer(Arc::clone(&budget)))
        .with(journal)
        .with(format)
        .init();
    budget.spawn_summaries();
}

/// Loads the configuration named on the command line, or the default one.
fn load_config(arg: &ConfigArg) -> Result<LoadedConfig, ConfigError> {
    if let Some(loaded) = arg
        .machine
        .as_deref()
        .and_then(pkm_plc::compose::machines::configuration)
    {
        return loaded;
    }
    let path = arg.config.clone().or_else(config::default_path);
    config::load(path.as_deref())
}

/// Loads the configuration named on the command line (or the default one) and resolves its
/// machine.
fn load_setup(arg: &ConfigArg) -> Result<Setup, ConfigError> {
    Setup::new(load_config(arg)?)
}

/// Builds a PLC through the composition root.
fn build(arg: &ConfigArg, options: Options) -> Result<Built, Failure> {
    compose::build(load_setup(arg)?, options).map_err(|e| Failure::usage(e.0))
}

fn cmd_check(args: ConfigArg) -> Result<(), Failure> {
    let Built { setup, plc, .. } = build(&args, Options::default())?;
    let loaded = &setup.loaded;
    let classes: Vec<String> = plc
        .classes()
        .map(|c| format!("{} ({} ms)", c.name, c.period_ns as f64 / 1e6))
        .collect();
    println!(
        "{}: valid ({} task classes: {}; {} process-image variables; I/O map: {})",
        loaded.origin,
        classes.len(),
        classes.join(", "),
        plc.vars().vars().len(),
        loaded.config.io_map.as_deref().unwrap_or("none")
    );
    Ok(())
}

fn cmd_run(args: RunArgs) -> Result<(), Failure> {
    let screen = screen_options(&args)?;
    let opcua = cli::opcua::options(
        args.opcua.as_deref(),
        args.opcua_users.as_ref(),
        args.opcua_pki.as_ref(),
        args.opcua_max_sessions,
        args.virtual_time,
    )
    .map_err(Failure::usage)?;
    // Programs are loaded, and commands come, from the screen or over OPC UA.
    let served = screen.is_some() || opcua.is_some();
    // In virtual time a joystick path is a capture file, played on the simulated clock;
    // `auto` (a live device) is off.
    let joystick = match (&args.joystick, args.virtual_time) {
        (JoystickSpec::Path(p), true) => JoystickChoice::Capture(p.clone()),
        (_, true) => JoystickChoice::Live(JoystickSpec::None),
        (spec, false) => JoystickChoice::Live(spec.clone()),
    };
    let programs = program_library(&args, served)?;
    let options = Options {
        bus: args.bus,
        link: pkm_plc::services::io::modbus::ModbusOptions {
            exchange: args.exchange.into(),
            max_input_age: Duration::from_millis(args.max_input_age_ms),
            max_exchange: Duration::from_millis(args.max_exchange_ms),
            ..Default::default()
        },
        scenario: args.scenario.clone(),
        joystick,
        program: args.program.clone(),
        programs,
        hmi: served,
    };
    let Built {
        setup,
        mut plc,
        joystick,
        library,
        refused,
        hmi,
    } = build(&args.config, options)?;
    let loaded = &setup.loaded;
    // Each reason starts with the file's name.
    for (_, why) in &refused {
        info!("screen: not offered: {}", why.lines().next().unwrap_or_default());
    }
    let summary_file = args.summary.as_deref().map(OutputFile::create).transpose()?;
    if let Some(path) = &args.trace {
        let digest = setup.digest()?;
        let recorder = pkm_plc::services::trace::record::Recorder::create_with(path, &plc, &digest, library.as_ref())
            .map_err(|e| Failure::run(format!("{}: cannot create the trace: {e}", path.display())))?;
        plc.set_recorder(Box::new(recorder));
    }
    info!("configuration: {}; bus: {}", loaded.origin, plc.bus_name());
    if plc.app_program().is_some_and(|p| p.starts_with("selftest.")) {
        warn!("running the runtime's built-in self-test programs, not a machine's application");
    }
    // A trace that could not be written fails the run, but only after the summary.
    let trace_failure;
    let summary = if args.virtual_time {
        let duration = args
            .duration
            .ok_or_else(|| Failure::usage("--virtual needs --duration"))?;
        let duration_ns = (duration * 1e9) as u64;
        let report = run::run_virtual(&mut plc, duration_ns);
        info!(
            "virtual time: {:.3} s simulated in {:.3} s wall-clock ({:.0}x)",
            duration,
            report.wall.as_secs_f64(),
            duration / report.wall.as_secs_f64().max(1e-9)
        );
        trace_failure = finish_trace(&mut plc);
        Summary::collect(&plc, "virtual", &loaded.origin, report.simulated_ns).with_program(&plc, library.as_ref())
    } else {
        let timing = &loaded.config.timing;
        let options = RealTimeOptions {
            source: args.time_source.map_or(timing.source, TimeSourceKind::from),
            realtime_priority: timing.realtime_priority,
            lock_memory: timing.lock_memory,
            spin_ns: u64::from(timing.spin_us) * 1000,
            duration_ns: args.duration.map(|d| (d * 1e9) as u64),
        };
        info!(
            "real time, time source {}; Ctrl-C stops",
            options.source.resolve().name()
        );
        let probe = match joystick {
            Some(j) => {
                let compose::Joystick {
                    spec,
                    feed,
                    probe,
                    stop,
                } = j;
                pkm_plc::services::io::hid::spawn_reader(spec, loaded.config.joystick.clone(), feed, Arc::clone(&stop))
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
        let opcua = match (opcua, &hmi) {
            (Some((options, next_ports)), Some(sink)) => Some(OpcUa {
                info: cli::opcua::space_info(&plc, &setup, program_files),
                options,
                explicit: args.opcua.is_some(),
                next_ports,
                sink: sink.clone(),
            }),
            _ => None,
        };
        let screen = match (screen, hmi) {
            (Some(options), Some(sink)) => Some(Screen {
                info: screen_info(&plc, &setup, library.as_ref(), refused),
                options,
                sink,
            }),
            _ => None,
        };
        let mut outcome = run_realtime(plc, options, screen, opcua)?;
        if let Some((probe, stop)) = probe {
            stop.store(true, std::sync::atomic::Ordering::Relaxed);
            if let Some(l) = probe.summary(outcome.epoch_ns) {
                info!(
                    "joystick: {} reports taken into the process image, {:.1} ms mean, {:.1} ms max after the reader handed them over",
                    l.count, l.mean_ms, l.max_ms
                );
            }
        }
        trace_failure = finish_trace(&mut outcome.plc).and_then(|()| bus_came_up(&outcome.plc));
        let mut s = Summary::collect(&outcome.plc, "real-time", &loaded.origin, outcome.elapsed_ns)
            .with_program(&outcome.plc, library.as_ref());
        s.time_source = Some(outcome.source.name());
        s.realtime_priority = Some(outcome.realtime_priority);
        s
    };
    for line in summary.lines() {
        info!("{line}");
    }
    if let Some(file) = summary_file {
        let path = file.path.clone();
        file.write(&summary.to_json())?;
        info!("summary written to {}", path.display());
    }
    trace_failure
}

/// Runs in real time on a tokio runtime that watches for the terminating signals (Ctrl-C,
/// SIGTERM, SIGHUP, …: [`pkm_plc::runtime::signals`]) and draws the status line, while the cyclic thread
/// does the work.
/// The environment variable whose address the screen is served at when `--hmi` is not given.
const HMI_ENV: &str = "PKM_PLC_HMI";

/// The operator's screen of a real-time run: where, what it shows at connection, where its
/// commands go.
struct Screen {
    options: pkm_plc::services::hmi::HmiOptions,
    info: pkm_plc::services::hmi::server::HmiInfo,
    sink: pkm_plc::services::hmi::commands::CommandSink,
}

/// The OPC UA server of a real-time run: where, what it shows, where its commands go.
struct OpcUa {
    options: pkm_plc::services::opcua::OpcUaOptions,
    /// The next ports tried when the address's is taken (the default address only).
    next_ports: u16,
    /// Asked for with --opcua (a server that cannot start ends the run), not the default.
    explicit: bool,
    info: pkm_plc::services::opcua::space::SpaceInfo,
    sink: pkm_plc::services::hmi::commands::CommandSink,
}

/// The screen `args` ask for: `None` in virtual time or with `--hmi none`.
fn screen_options(args: &RunArgs) -> Result<Option<pkm_plc::services::hmi::HmiOptions>, Failure> {
    // The environment's address stands in for --hmi in real time (a virtual run serves none,
    // whatever the environment says).
    let hmi = match (args.hmi, std::env::var(HMI_ENV)) {
        (None, Ok(text)) if !args.virtual_time => {
            Some(parse_hmi(&text).map_err(|e| Failure::usage(format!("{HMI_ENV}={text}: {e}")))?)
        }
        (hmi, _) => hmi,
    };
    let next_ports = if hmi.is_none() {
        pkm_plc::services::hmi::DEFAULT_NEXT_PORTS
    } else {
        0
    };
    let addr = match (hmi, args.virtual_time) {
        (Some(HmiAddr::Off), _) | (None, true) => return Ok(None),
        (Some(HmiAddr::At(_)), true) => {
            return Err(Failure::usage(
                "--hmi serves the screen in real time only; a --virtual run has none",
            ));
        }
        (Some(HmiAddr::At(a)), false) => a,
        (None, false) => pkm_plc::services::hmi::DEFAULT_ADDR
            .parse()
            .map_err(|e| Failure::usage(format!("{}: {e}", pkm_plc::services::hmi::DEFAULT_ADDR)))?,
    };
    let token = match (&args.hmi_token, &args.hmi_token_file) {
        (Some(t), _) => Some(t.clone()),
        (None, Some(path)) => {
            let text = pkm_plc::runtime::files::read_text(path, 4096)
                .map_err(|e| Failure::usage(format!("--hmi-token-file {}: {e}", path.display())))?;
            Some(text.lines().next().unwrap_or("").trim().to_string())
        }
        (None, None) => None,
    };
    let options = pkm_plc::services::hmi::HmiOptions {
        addr,
        token,
        allowed_origins: args
            .hmi_allow_origin
            .iter()
            .map(|o| o.trim_end_matches('/').to_ascii_lowercase())
            .collect(),
        max_clients: args.hmi_max_clients,
        next_ports,
    };
    options.check().map_err(Failure::usage)?;
    Ok(Some(options))
}

/// The directory of programs the screen offers: `--programs DIR`, or `programs` where it exists
/// (with a screen); `none` or no screen: none.
fn program_library(args: &RunArgs, screen: bool) -> Result<Option<PathBuf>, Failure> {
    match &args.programs {
        Some(dir) if dir.as_os_str() == "none" => Ok(None),
        Some(dir) if !screen => Err(Failure::usage(format!(
            "--programs {}: programs are loaded from the operator's screen or over OPC UA, which are served in real time only (and not with both --hmi none and --opcua none)",
            dir.display()
        ))),
        Some(dir) => Ok(Some(dir.clone())),
        None => Ok(Some(PathBuf::from("programs")).filter(|d| screen && d.is_dir())),
    }
}

/// What the screen shows at connection.
fn screen_info(
    plc: &Plc,
    setup: &Setup,
    library: Option<&pkm_api::trajectory::NcLibrary>,
    refused: Vec<(String, String)>,
) -> pkm_plc::services::hmi::server::HmiInfo {
    let motion = setup.machine.and_then(|m| m.motion(&setup.loaded.json).ok());
    pkm_plc::services::hmi::server::HmiInfo {
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
            .map(|j| pkm_plc::services::hmi::server::ScreenProgram {
                file: j.file.clone(),
                text: j.text.clone(),
                path: pkm_plc::services::hmi::server::preview(j.trajectory.as_ref()),
            })
            .collect(),
        refused,
        mechanism: pkm_plc::services::hmi::mechanism::Mechanism::of(setup, plc),
        axes: motion
            .as_ref()
            .map(|m| m.axes.iter().map(|a| a.to_string()).collect())
            .unwrap_or_default(),
        joints: motion
            .map(|m| m.joint_vars.iter().map(|v| v.to_string()).collect())
            .unwrap_or_default(),
        jobs: library
            .zip(pkm_plc::compose::screen_job::StandingPose::of(setup, plc))
            .map(|(l, standing)| {
                let loaded = plc
                    .vars()
                    .index_of(pkm_api::trajectory::vars::NC_PROGRAM.name())
                    .map(usize::from);
                pkm_plc::services::hmi::jobs::JobDesk::new(setup.clone(), l.clone(), standing, loaded)
            }),
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

fn run_realtime(
    plc: Plc,
    options: RealTimeOptions,
    screen: Option<Screen>,
    opcua: Option<OpcUa>,
) -> Result<run::RealTimeOutcome, Failure> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| Failure::run(format!("cannot start the tokio runtime: {e}")))?;
    // The handlers before the first cycle: a signal from then on stops the run safely.
    let mut signals = {
        let _inside = runtime.enter();
        pkm_plc::runtime::signals::Terminating::register()
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
            let (addr, next) = (server.options.addr, server.next_ports);
            let instead = "give another endpoint with --opcua opc.tcp://HOST:PORT (port 0: any free one, logged), or run without OPC UA with --opcua none";
            runtime
                .block_on(listen(addr, next, "OPC UA", instead))
                .map(|listener| (server, listener))
        })
        .transpose()?;
    // Both are fed from one publication per main cycle.
    let (publisher, feed) = if screen.is_some() || opcua.is_some() {
        let (publisher, reader) = pkm_plc::runtime::frame::frames(&plc);
        (Some(publisher), Some(pkm_plc::runtime::frame::FrameFeed::spawn(reader)))
    } else {
        (None, None)
    };
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
    let stop = run.stop_flag();
    let snapshot = run.snapshot();
    let heartbeat = run.heartbeat();
    // A service manager's notifications (systemd, Type=notify), when it asked for them.
    let mut notifier = pkm_plc::runtime::service::Notifier::from_env();
    let outcome = runtime.block_on(async move {
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
                        info!("running in real time; Ctrl-C, SIGTERM or SIGHUP stops it safely");
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
    });
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

/// Serves the operator's screen on `listener` (inside the tokio runtime).
fn serve_screen(screen: Screen, listener: tokio::net::TcpListener, feed: pkm_plc::runtime::frame::FrameFeed) {
    let Screen { options, info, sink } = screen;
    let server_options = pkm_plc::services::hmi::server::ServerOptions {
        access: pkm_plc::services::hmi::access::Access {
            token: options.token.clone(),
            allowed_origins: options.allowed_origins.clone(),
        },
        max_clients: options.max_clients,
    };
    let router = pkm_plc::services::hmi::server::router(info, feed, sink, server_options);
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
    let listener = pkm_plc::services::hmi::listener::Bounded::new(listener, options.max_clients + 8);
    tokio::spawn(async move {
        let service = router.into_make_service_with_connect_info::<pkm_plc::services::hmi::listener::Peer>();
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
    feed: pkm_plc::runtime::frame::FrameFeed,
    main_period_ns: u64,
) -> Result<(), Failure> {
    let OpcUa {
        options,
        info,
        sink,
        explicit,
        ..
    } = server;
    match pkm_plc::services::opcua::server::start(&options, listener, info, feed, sink, main_period_ns) {
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
        .downcast_ref::<pkm_plc::services::io::modbus::ModbusBus>()
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

fn cmd_replay(args: ReplayArgs) -> Result<(), Failure> {
    use pkm_plc::compose::replay::{ReplayError, replay};
    let setup = if args.config.config.is_none() && args.config.machine.is_none() {
        // The trace says which machine it was recorded on.
        let machine = recorded_machine(&args.trace);
        let arg = ConfigArg {
            config: None,
            machine: machine.map(str::to_string),
        };
        load_setup(&arg)?
    } else {
        load_setup(&args.config)?
    };
    match replay(&args.trace, &setup, args.force) {
        Ok(r) => {
            let (identical, cut) = match &r.cut {
                None => ("identical", String::new()),
                Some(cut) => ("identical up to the cut", format!("; {cut}")),
            };
            println!(
                "{}: {identical}: {} records over {:.1} s of recorded time, replayed in {:.3} s ({:.0}x){cut}",
                args.trace.display(),
                r.records,
                r.recorded_s,
                r.wall.as_secs_f64(),
                r.recorded_s / r.wall.as_secs_f64().max(1e-9)
            );
            Ok(())
        }
        Err(e @ ReplayError::Differs(_)) => Err(Failure::run(format!("{}: {e}", args.trace.display()))),
        Err(e) => Err(Failure::usage(e.to_string())),
    }
}

/// The machine whose own configuration a trace was recorded with (its header's digest is that
/// configuration's), if one's is.
fn recorded_machine(trace: &std::path::Path) -> Option<&'static str> {
    let reader = pkm_plc::services::trace::read::TraceReader::open(trace).ok()?;
    pkm_plc::compose::machines::with_digest(&reader.header().config_digest)
}

fn cmd_trace(args: TraceArgs) -> Result<(), Failure> {
    use pkm_plc::services::trace::export::{ExportError, to_svg, to_vcd};
    if let TraceOp::Summary { trace, every } = &args.op {
        let text = pkm_plc::services::trace::expected::summary(trace, (every * 1e6) as u64)
            .map_err(|e| Failure::usage(e.to_string()))?;
        print!("{text}");
        return Ok(());
    }
    let (result, out) = match &args.op {
        TraceOp::Vcd { trace, out } => (to_vcd(trace, out), out),
        TraceOp::Plot { trace, out, vars } => (to_svg(trace, out, vars), out),
        TraceOp::Path { trace, out, magnify } => (pkm_plc::services::trace::path::to_svg(trace, out, *magnify), out),
        TraceOp::Summary { .. } => unreachable!("handled above"),
    };
    match result {
        Ok(done) => {
            let cut = done.cut.map(|c| format!(" ({c})")).unwrap_or_default();
            println!("{}: {} records written{cut}", out.display(), done.records);
            Ok(())
        }
        Err(e @ ExportError::Output { .. }) => Err(Failure::run(e.to_string())),
        Err(e) => Err(Failure::usage(e.to_string())),
    }
}

fn cmd_registers(args: ConfigArg) -> Result<(), Failure> {
    let setup = load_setup(&args)?;
    let Some(map) = setup.io_map()? else {
        return Err(Failure::usage(format!(
            "{}: the configuration names no I/O map",
            setup.origin()
        )));
    };
    print!(
        "{}",
        pkm_plc::services::io::registers::RegisterMap::of(&map).report(&map)
    );
    Ok(())
}

fn cmd_station(args: StationArgs) -> Result<(), Failure> {
    use cli::station;
    let StationOp::Scan {
        address,
        write_map,
        timeout_ms,
    } = args.op;
    let address = station::parse_address(&address).map_err(|e| Failure::usage(e.to_string()))?;
    let scan = station::scan(address, Duration::from_millis(timeout_ms)).map_err(|e| Failure::run(e.to_string()))?;
    print!("{}", scan.report());
    if let Some(path) = write_map {
        station::write_map(&path, &scan.map_skeleton()).map_err(Failure::run)?;
        println!(
            "I/O map skeleton for {} modules written to {}: add the bindings, name any module of an unknown ID",
            scan.modules.len(),
            path.display()
        );
    }
    Ok(())
}

fn cmd_io_sim(args: IoSimArgs) -> Result<(), Failure> {
    use std::io::Write;
    let setup = load_setup(&args.config)?;
    let bus = setup.sim_bus(args.scenario.as_deref())?;
    // A serial line's station is the generic one; over TCP, the one the I/O map names.
    let mut station = match args.serial {
        Some(_) => pkm_plc::services::sim::modbus::Station::new(bus),
        None => pkm_plc::services::sim::modbus::Station::of_map(bus, args.node),
    };
    let [coils, discrete, input, holding] = station.registers().sizes();
    let kind = if station.is_bus_controller() {
        format!(
            "an X20BC0087 (node {}) with {} modules",
            args.node,
            station.registers().modules.len()
        )
    } else {
        "a generic station".to_string()
    };
    let options = pkm_plc::services::sim::server::ServerOptions {
        watchdog: (args.watchdog_ms > 0).then(|| Duration::from_millis(args.watchdog_ms)),
        max_connections: usize::from(args.max_connections),
        idle_timeout: Duration::from_secs(args.idle_timeout_s),
    };
    let watchdog = match options.watchdog {
        Some(w) => format!("output watchdog {} ms", w.as_millis()),
        None => "output watchdog OFF".to_string(),
    };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|e| Failure::run(format!("cannot start the tokio runtime: {e}")))?;
    runtime.block_on(async move {
        let mut signals = pkm_plc::runtime::signals::Terminating::register();
        let stopped = |name: &str| {
            info!("io-sim: {name}: stopping");
            Ok(())
        };
        if let Some((path, baud)) = &args.serial {
            let stream = tokio_serial::SerialStream::open(&tokio_serial::new(path.as_str(), *baud))
                .map_err(|e| Failure::run(format!("io-sim: cannot open {path}: {e}")))?;
            info!("io-sim: {} on {path} at {baud} baud as Modbus RTU, {watchdog}; Ctrl-C stops", setup.origin());
            return tokio::select! {
                served = pkm_plc::services::sim::server::serve_rtu(stream, station, options) => served.map_err(|e| Failure::run(format!("io-sim: {e}"))),
                name = signals.recv() => stopped(&name),
            };
        }
        let tcp = args.tcp.ok_or_else(|| Failure::usage("io-sim needs --tcp or --serial"))?;
        let listener = tokio::net::TcpListener::bind(tcp)
            .await
            .map_err(|e| Failure::run(format!("io-sim: cannot listen on {tcp}: {e}")))?;
        let address = listener.local_addr().map_err(|e| Failure::run(e.to_string()))?;
        station.set_address(address);
        println!("{address}");
        let _ = std::io::stdout().flush();
        if !address.ip().is_loopback() {
            warn!(
                "io-sim: listening on {address}, not on loopback: Modbus has no authentication, so anyone who \
                 reaches this address can write the outputs (the drives). Use 127.0.0.1 unless a trusted, \
                 separate network needs it."
            );
        }
        info!(
            "io-sim: {} on {address} as Modbus TCP, {kind}: {coils} coils, {discrete} discrete inputs, {input} input \
             registers, {holding} holding registers; {watchdog}, at most {} clients; Ctrl-C stops",
            setup.origin(), options.max_connections
        );
        tokio::select! {
            served = pkm_plc::services::sim::server::serve_tcp(listener, station, options) => {
                served.map_err(|e| Failure::run(format!("io-sim: {e}")))
            }
            name = signals.recv() => stopped(&name),
        }
    })
}

fn cmd_bench(args: BenchArgs) -> Result<(), Failure> {
    let options = BenchOptions {
        seconds: args.seconds,
        cycle_us: args.cycle_us,
        sources: args
            .sources
            .iter()
            .map(|s| TimeSourceKind::from(*s).resolve())
            .collect(),
        realtime_priority: args.realtime_priority,
        spin_us: args.spin_us,
    };
    if !(config::MIN_CYCLE_US..=config::MAX_CYCLE_US).contains(&options.cycle_us) {
        return Err(Failure::usage(format!(
            "--cycle-us must be between {} and {}",
            config::MIN_CYCLE_US,
            config::MAX_CYCLE_US
        )));
    }
    let json_file = args.json.as_deref().map(OutputFile::create).transpose()?;
    let rows = bench::run(&options, |row| info!("measuring {row}")).map_err(|e| Failure::run(e.to_string()))?;
    print!("{}", bench::table(&rows));
    if let Some(file) = json_file {
        let json = serde_json::to_string_pretty(&rows).map_err(|e| Failure::run(e.to_string()))?;
        file.write(&json)?;
    }
    Ok(())
}

fn cmd_link_bench(args: LinkBenchArgs) -> Result<(), Failure> {
    if args.exchange.contains(&Exchange::Auto) {
        return Err(Failure::usage("--exchange: name the modes to measure (tables, image)"));
    }
    let setup = load_setup(&args.config)?;
    let options = cli::link_bench::LinkBenchOptions {
        baud: args.baud,
        seconds: args.seconds,
        modes: args.exchange.into_iter().map(ExchangeMode::from).collect(),
    };
    let json_file = args.json.as_deref().map(OutputFile::create).transpose()?;
    let rows = cli::link_bench::run(&setup, &options, |row| info!("measuring {row}")).map_err(|e| match e {
        cli::link_bench::LinkBenchError::Setup(_) => Failure::run(e.to_string()),
        _ => Failure::usage(e.to_string()),
    })?;
    print!("{}", cli::link_bench::table(&rows));
    if let Some(file) = json_file {
        let json = serde_json::to_string_pretty(&rows).map_err(|e| Failure::run(e.to_string()))?;
        file.write(&json)?;
    }
    Ok(())
}

/// An output file opened before the work that fills it, so that a path that cannot be written
/// fails at once instead of after a run or a measurement.
struct OutputFile {
    path: PathBuf,
    file: std::fs::File,
}

impl OutputFile {
    /// Creates (or empties) the file at `path`: a usage error if that is not possible.
    fn create(path: &Path) -> Result<OutputFile, Failure> {
        let file = std::fs::File::create(path)
            .map_err(|e| Failure::usage(format!("{}: cannot write: {e}", path.display())))?;
        Ok(OutputFile {
            path: path.to_path_buf(),
            file,
        })
    }

    /// Writes `text` and a newline, and closes the file.
    fn write(mut self, text: &str) -> Result<(), Failure> {
        use std::io::Write;
        self.file
            .write_all(format!("{text}\n").as_bytes())
            .and_then(|()| self.file.sync_data())
            .map_err(|e| Failure::run(format!("{}: cannot write: {e}", self.path.display())))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn cli_definition_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn seconds_must_be_positive_and_finite() {
        assert_eq!(parse_seconds("2.5"), Ok(2.5));
        assert!(parse_seconds("0").is_err());
        assert!(parse_seconds("-1").is_err());
        assert!(parse_seconds("inf").is_err());
        assert_eq!(parse_seconds("ten"), Err("\"ten\" is not a number of seconds".into()));
    }
}
