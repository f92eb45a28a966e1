//! The command line's definition: the subcommands, their arguments, and the parsers of values
//! that clap does not know (seconds, a screen address, a serial line, a bus).

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};

use super::enums::{Exchange, TimeSource};
use pkm_kinematics::Machine;
use pkm_plc::compose::BusChoice;
use pkm_plc::services::io::hid::JoystickSpec;

/// A soft-PLC for parallel-kinematic machine models.
#[derive(Parser, Debug)]
#[command(name = "pkm-plc", version, about, propagate_version = true)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Run the soft-PLC (real time until Ctrl-C, or virtual time for a given duration).
    Run(Box<RunArgs>),
    /// Validate a configuration without running anything.
    Check(ConfigArg),
    /// Measure the time sources side by side (cycle start lateness of a 10 ms class).
    Bench(BenchArgs),
    /// Kinematics of a machine model: fk, ik, workspace, bench, convergence.
    Kin(KinArgs),
    /// NC programs: check one against the configured machine.
    Nc(NcArgs),
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
    /// io-sim in this process, joined by socket pairs paced at the baud rate).
    LinkBench(LinkBenchArgs),
    /// The real station: `station scan tcp:HOST[:PORT]` lists an X20BC0087's identity,
    /// network settings, modules, watchdog and error bits (read-only).
    Station(StationArgs),
}

#[derive(Args, Debug)]
pub struct StationArgs {
    #[command(subcommand)]
    pub op: StationOp,
}

#[derive(Subcommand, Debug)]
pub enum StationOp {
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
pub struct LinkBenchArgs {
    /// The line's baud rate.
    #[arg(long, default_value_t = 115_200, value_parser = clap::value_parser!(u32).range(1200..=4_000_000))]
    pub baud: u32,
    /// Seconds per exchange mode.
    #[arg(long, default_value_t = 10.0, value_parser = parse_seconds)]
    pub seconds: f64,
    /// The exchange modes to measure.
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [Exchange::Tables, Exchange::Image])]
    pub exchange: Vec<Exchange>,
    #[command(flatten)]
    pub config: ConfigArg,
    /// Also write the rows as JSON to FILE.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub struct IoSimArgs {
    /// Serve Modbus TCP on this address (port 0: any free port; the address is printed first).
    #[arg(
        long,
        value_name = "ADDR",
        required_unless_present = "serial",
        conflicts_with = "serial"
    )]
    pub tcp: Option<std::net::SocketAddr>,
    /// Serve Modbus RTU on this serial device, `PATH[@BAUD]` (115 200 baud by default).
    #[arg(long, value_name = "PATH[@BAUD]", value_parser = parse_serial)]
    pub serial: Option<(String, u32)>,
    #[command(flatten)]
    pub config: ConfigArg,
    /// A scenario for the simulated machine (panel inputs and faults).
    #[arg(long, value_name = "FILE")]
    pub scenario: Option<PathBuf>,
    /// Output watchdog: every output goes to its safe value (zero) when no write request arrives
    /// for this long, as a real bus coupler's outputs do when the controller dies; 0 turns it off.
    /// An X20BC0087 station (over TCP) starts with it as its stored setting, which clients change.
    #[arg(long, value_name = "MS", default_value_t = 100)]
    pub watchdog_ms: u64,
    /// An X20BC0087 station's node number (its rotary switches), which it reports.
    #[arg(long, value_name = "N", default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=255))]
    pub node: u16,
    /// Modbus TCP clients served at once; more are closed as they connect.
    #[arg(long, value_name = "N", default_value_t = 8, value_parser = clap::value_parser!(u16).range(1..))]
    pub max_connections: u16,
    /// A Modbus TCP client that sends no request for this long is disconnected (seconds).
    #[arg(long, value_name = "S", default_value_t = 60, value_parser = clap::value_parser!(u64).range(1..))]
    pub idle_timeout_s: u64,
    /// SCHED_FIFO priority of the thread that answers requests (and advances the plant to each
    /// request's time), as a station's own processor is never starved by the PC's other work;
    /// below the PLC's cyclic thread (80). 0, or where the process may not (no root or
    /// CAP_SYS_NICE): normal scheduling.
    #[arg(long, value_name = "N", default_value_t = 70, value_parser = clap::value_parser!(u8).range(0..=99))]
    pub realtime_priority: u8,
    /// When it stops, write what the simulated machine truly did to FILE (JSON): each joint's
    /// position and the steps its stepper lost, to hold against what the PLC believes.
    #[arg(long, value_name = "FILE")]
    pub summary: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub struct TraceArgs {
    #[command(subcommand)]
    pub op: TraceOp,
}

#[derive(Subcommand, Debug)]
pub enum TraceOp {
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
pub fn parse_magnification(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if (1.0..=100_000.0).contains(&v) => Ok(v),
        _ => Err(format!("must be a number from 1 to 100000, got {s}")),
    }
}

#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// The trace (JSON Lines, from `run --trace`).
    #[arg(value_name = "TRACE")]
    pub trace: PathBuf,
    #[command(flatten)]
    pub config: ConfigArg,
    /// Replay even if the trace was recorded with another configuration or I/O map.
    #[arg(long)]
    pub force: bool,
}

#[derive(Args, Debug)]
pub struct ConfigArg {
    /// Configuration file [default: ./config.json if present, else the built-in one].
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// A machine's own configuration: short for `--config machines/NAME.json` (the TRIJOINT's is
    /// config.json); the built-in copy when the file is not there.
    #[arg(long, value_name = "NAME", conflicts_with = "config",
          value_parser = clap::builder::PossibleValuesParser::new(pkm_plc::compose::machines::BUILTIN.iter().map(|m| m.name())))]
    pub machine: Option<String>,
}

#[derive(Args, Debug)]
pub struct RunArgs {
    #[command(flatten)]
    pub config: ConfigArg,
    /// Run in virtual time: as fast as the CPU allows, deterministic. Needs --duration, or
    /// --pace.
    #[arg(long = "virtual")]
    pub virtual_time: bool,
    /// With --virtual: a simulation paced at X times real time (1 … 50), served with the
    /// operator's screen and OPC UA as a real-time run is, until stopped (or --duration of
    /// simulated time) — to watch a program on the simulated machine and see its limits before
    /// it runs on the real one. The cycles stay in virtual time: deterministic, never late.
    #[arg(long, value_name = "X", requires = "virtual_time", value_parser = parse_pace)]
    pub pace: Option<f64>,
    /// Stop after this many seconds (of simulated time with --virtual).
    #[arg(long, value_name = "SECONDS", value_parser = parse_seconds)]
    pub duration: Option<f64>,
    /// Write a JSON summary (cycle statistics, final state) to FILE at exit.
    #[arg(long, value_name = "FILE")]
    pub summary: Option<PathBuf>,
    /// The field bus: `sim` (the configured machine's simulated plant behind its I/O map),
    /// `tcp:HOST:PORT` (a Modbus TCP station serving the I/O map's register map),
    /// `serial:PATH[@BAUD]` (the same over Modbus RTU, 115 200 baud by default), or `none`.
    #[arg(long, default_value = "sim", value_parser = parse_bus)]
    pub bus: BusChoice,
    /// How a Modbus bus exchanges the I/O each time: `tables` (four requests on the standard
    /// tables, any server), `image` (one read/write-multiple-registers request on the packed
    /// process image, as io-sim serves it), or `auto` (image on serial, tables on TCP).
    #[arg(long, value_enum, default_value_t = Exchange::Auto)]
    pub exchange: Exchange,
    /// A Modbus bus faults when its newest complete input image is older than this (ms), however
    /// the exchanges fail: slow responses that never time out count too.
    #[arg(long, value_name = "MS", default_value_t = 50, value_parser = clap::value_parser!(u64).range(1..))]
    pub max_input_age_ms: u64,
    /// A Modbus bus faults when its exchanges take longer than this (the median of the last
    /// five, ms): the drive regulators were tuned for inputs this fresh, and oscillate on a
    /// slower link. Raise it only after checking the regulators on that link.
    #[arg(long, value_name = "MS", default_value_t = 8, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub max_exchange_ms: u64,
    /// A scenario for the simulated machine: timed operator actions and faults (JSON).
    #[arg(long, value_name = "FILE")]
    pub scenario: Option<PathBuf>,
    /// The HID joystick: an input device (`/dev/input/eventN`), a FIFO or capture file of raw
    /// `struct input_event` records, `auto` (the first joystick or gamepad; none: panel
    /// buttons only), or `none` (the bus's own joystick channels, e.g. the simulated machine's).
    #[arg(long, value_name = "DEVICE|FILE|auto|none", default_value = "auto")]
    pub joystick: JoystickSpec,
    /// Record every class cycle (inputs, outputs, main state) to FILE (JSON Lines).
    #[arg(long, value_name = "FILE")]
    pub trace: Option<PathBuf>,
    /// An NC program (G-code) to run: checked and planned at start (refused with exit code 2
    /// if it cannot run), started once the machine is READY after referencing (state AUTO).
    #[arg(long, value_name = "FILE")]
    pub program: Option<PathBuf>,
    /// The tool table NC programs are read with (LinuxCNC's `tool.tbl` format), in place of the
    /// configuration's `nc.tool_table`.
    #[arg(long, value_name = "FILE")]
    pub tool_table: Option<PathBuf>,
    /// The parameter file (LinuxCNC's `.var` format) that keeps the work offsets and G28/G30
    /// positions across runs, in place of the configuration's `nc.var_file`: programs start
    /// from it, a touch-off on the screen writes it (created then if it does not exist).
    #[arg(long, value_name = "FILE")]
    pub var_file: Option<PathBuf>,
    /// The programs (`*.ngc`) the operator may load from the screen, each checked and planned
    /// at start (those that cannot run on the machine are listed with why), or `none`. Real
    /// time with a screen only; default `programs` (if that directory exists).
    #[arg(long, value_name = "DIR|none")]
    pub programs: Option<PathBuf>,
    /// The operator's screen: `ADDR` (host:port) to serve it at, or `none`. Real time only;
    /// default 127.0.0.1:8080, or the environment's PKM_PLC_HMI (another address than loopback
    /// needs --hmi-token).
    #[arg(long, value_name = "ADDR|none", value_parser = parse_hmi)]
    pub hmi: Option<HmiAddr>,
    /// The screen's commands (STOP, jog, program) need this token; without it a page watches.
    #[arg(long, value_name = "TOKEN", conflicts_with = "hmi_token_file")]
    pub hmi_token: Option<String>,
    /// As --hmi-token, the token read from FILE (its first line).
    #[arg(long, value_name = "FILE")]
    pub hmi_token_file: Option<PathBuf>,
    /// Another origin (`scheme://host[:port]`) whose pages may open the screen's WebSocket, and
    /// whose host the screen answers to (a reverse proxy's, say); repeatable. The screen's own
    /// page is always allowed.
    #[arg(long, value_name = "ORIGIN")]
    pub hmi_allow_origin: Vec<String>,
    /// The most clients the screen serves at once.
    #[arg(long, value_name = "N", default_value_t = pkm_plc::services::hmi::DEFAULT_MAX_CLIENTS)]
    pub hmi_max_clients: usize,
    /// The OPC UA server: `opc.tcp://HOST:PORT` to serve it at, or `none`. Real time only;
    /// default opc.tcp://127.0.0.1:4840 (another address than loopback needs --opcua-users).
    #[arg(long, value_name = "URL|none", env = "PKM_PLC_OPCUA")]
    pub opcua: Option<String>,
    /// The users who may command over OPC UA (a JSON file of names with a password or a
    /// certificate); without it the server is read-only.
    #[arg(long, value_name = "FILE")]
    pub opcua_users: Option<PathBuf>,
    /// The OPC UA server's certificate store: its certificate and key (made on first use) and
    /// the clients' trusted/ and rejected/ certificates. Default: one per machine,
    /// $XDG_DATA_HOME/pkm-plc/opcua-pki/MACHINE (~/.local/share/pkm-plc/opcua-pki/MACHINE).
    #[arg(long, value_name = "DIR")]
    pub opcua_pki: Option<PathBuf>,
    /// The most OPC UA sessions at once.
    #[arg(long, value_name = "N", default_value_t = pkm_plc::services::opcua::DEFAULT_MAX_SESSIONS)]
    pub opcua_max_sessions: usize,
    /// Override the configured time source (real time only).
    #[arg(long, value_enum, value_name = "SOURCE", conflicts_with = "virtual_time")]
    pub time_source: Option<TimeSource>,
}

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Seconds per measured row.
    #[arg(long, default_value_t = 30.0, value_parser = parse_seconds)]
    pub seconds: f64,
    /// Cycle time of the measured task class (µs).
    #[arg(long, default_value_t = 10_000)]
    pub cycle_us: u32,
    /// The time sources to measure.
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [TimeSource::Tokio, TimeSource::Timerfd, TimeSource::Nanosleep])]
    pub sources: Vec<TimeSource>,
    /// SCHED_FIFO priority for the real-time rows (0 skips them).
    #[arg(long, default_value_t = 80)]
    pub realtime_priority: u8,
    /// Also measure each source with this spin margin (µs) before each release (0: skip).
    #[arg(long, default_value_t = 0)]
    pub spin_us: u32,
    /// Also write the rows as JSON to FILE.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
}

/// Where the operator's screen is served.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HmiAddr {
    /// Not at all.
    Off,
    /// At this address.
    At(std::net::SocketAddr),
}

pub fn parse_hmi(s: &str) -> Result<HmiAddr, String> {
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
pub fn parse_serial(s: &str) -> Result<(String, u32), String> {
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

pub fn parse_bus(s: &str) -> Result<BusChoice, String> {
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

pub fn parse_seconds(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("\"{s}\" is not a number of seconds"))?;
    if v.is_finite() && v > 0.0 && v <= 1e7 {
        Ok(v)
    } else {
        Err(format!("must be more than 0 and at most 10000000 seconds, got {s}"))
    }
}

/// A simulation's pace: 1 … 50 times real time.
pub fn parse_pace(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("\"{s}\" is not a number"))?;
    if v.is_finite() && (1.0..=50.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("a simulation runs at 1 … 50 times real time, got {s}"))
    }
}

/// Arguments of `pkm-plc kin`.
#[derive(Args, Debug)]
pub struct KinArgs {
    /// The machine model: trijoint, pn101, ox-x, ox-o or hexapod.
    #[arg(value_parser = parse_model)]
    pub machine: Machine,
    #[command(subcommand)]
    pub op: KinOp,
    /// Configuration file for the kinematic parameters [default: ./config.json if present,
    /// else the built-in one].
    #[arg(long, value_name = "FILE", global = true)]
    pub config: Option<PathBuf>,
}

/// What `kin` computes.
#[derive(Subcommand, Debug)]
pub enum KinOp {
    /// Joints (mm) → pose: prints {"machine", "joints", "pose"}.
    Fk {
        /// One value per joint, in mm.
        #[arg(allow_negative_numbers = true, required = true)]
        joints: Vec<f64>,
    },
    /// Pose (mm, degrees) → joints: prints {"machine", "joints", "pose"}.
    Ik {
        /// One value per pose coordinate (trijoint x y; pn101 and O-X x y z; hexapod x y z a b c).
        #[arg(allow_negative_numbers = true, required = true)]
        pose: Vec<f64>,
    },
    /// Sample the workspace; draw it as SVG and print a summary.
    Workspace {
        /// The SVG picture to write.
        #[arg(long, value_name = "FILE")]
        svg: PathBuf,
        /// Also write every reachable sample as JSON.
        #[arg(long, value_name = "FILE")]
        json: Option<PathBuf>,
        /// Samples along each sampled axis.
        #[arg(long, default_value_t = 60)]
        samples: usize,
        /// Smallest singularity measure kept.
        #[arg(long, default_value_t = 0.05)]
        threshold: f64,
    },
    /// Measure IK and FK calls per second over reachable poses.
    Bench {
        /// Seconds per measurement.
        #[arg(long, default_value_t = 1.0)]
        seconds: f64,
    },
    /// Hexapod only: Newton iterations of FK from the home pose for random poses.
    Convergence {
        /// Random poses to try.
        #[arg(long, default_value_t = 10_000)]
        samples: usize,
        /// Translation range around home (± mm).
        #[arg(long, default_value_t = 50.0)]
        translation: f64,
        /// Rotation range (± degrees).
        #[arg(long, default_value_t = 10.0)]
        rotation: f64,
        /// Seed of the pseudo-random poses.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
}

/// A kinematic model by its name on the command line.
pub fn parse_model(s: &str) -> Result<Machine, String> {
    Machine::from_name(s).ok_or_else(|| {
        let names: Vec<&str> = Machine::ALL.iter().map(|m| m.name()).collect();
        format!("\"{s}\" is not a machine model: use {}", names.join(", "))
    })
}

/// Arguments of `pkm-plc nc`.
#[derive(Args, Debug)]
pub struct NcArgs {
    #[command(subcommand)]
    pub op: NcOp,
}

/// What `nc` does.
#[derive(Subcommand, Debug)]
pub enum NcOp {
    /// Read and check a program: refusals with FILE:LINE:COLUMN (exit 2), unreachable points
    /// with their line (exit 1); else the path's length and bounding box (exit 0).
    Check {
        /// The program (G-code).
        file: PathBuf,
        #[command(flatten)]
        config: ConfigArg,
        /// Also write the report as JSON to FILE.
        #[arg(long, value_name = "FILE")]
        json: Option<PathBuf>,
        /// Also draw the tool path inside the machine's workspace as SVG to FILE.
        #[arg(long, value_name = "FILE")]
        svg: Option<PathBuf>,
        /// List every block whose feed the machine lowers, not one line per cause.
        #[arg(long)]
        verbose: bool,
        /// The tool table the program is read with (LinuxCNC's `tool.tbl` format), in place of
        /// the configuration's `nc.tool_table`.
        #[arg(long, value_name = "FILE")]
        tool_table: Option<PathBuf>,
        /// The parameter file whose work offsets the program is read with (LinuxCNC's `.var`
        /// format), in place of the configuration's `nc.var_file`.
        #[arg(long, value_name = "FILE")]
        var_file: Option<PathBuf>,
    },
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
