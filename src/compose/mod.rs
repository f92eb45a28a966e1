//! Composition: a configuration turned into a built PLC, and the built PLC's run.
//!
//! One place knows how to assemble a soft-PLC from a configuration: which machine it runs
//! ([`setup`], [`machines`]: its programs, configuration checks, I/O map and plant), which bus,
//! which joystick, which NC programs ([`nc_job`], [`screen_job`]) — [`build`] — and how the
//! built PLC runs with its screen and OPC UA server ([`serve`]) or replays a trace ([`replay`]).
//! The command line and the tests all come here, so they cannot drift apart. Every problem of
//! the configuration and its I/O map is reported at once, as one list per file. This layer
//! builds on the services and the runtime core; neither knows it.

pub mod machines;
pub mod nc_job;
pub mod replay;
pub mod screen_job;
pub mod selftest;
pub mod serve;
pub mod setup;

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use pkm_api::library::NcLibrary;
use tracing::{info, warn};

use crate::runtime::bus::{Bus, NoBus, UnknownBus};
use crate::runtime::config::ConfigError;
use crate::runtime::plc::Plc;
use crate::services::io::hid::{JoystickBus, JoystickFeed, JoystickSpec, LatencyProbe};
use crate::services::io::map::IoMap;
use crate::services::io::modbus::{ModbusBus, ModbusOptions, Transport};
pub use setup::Setup;

/// The buses a PLC can run on.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum BusChoice {
    /// The simulated machine.
    Sim,
    /// No field I/O (with an I/O map: a dry run, inputs held at zero).
    None,
    /// A Modbus TCP station.
    Tcp(std::net::SocketAddr),
    /// A Modbus RTU station on a serial line (path, baud).
    Serial(String, u32),
}

/// Where the operator's joystick comes from.
#[derive(Clone, Debug)]
pub enum JoystickChoice {
    /// A live source read by a thread (real time), or none.
    Live(JoystickSpec),
    /// A capture file played on the simulated clock (virtual time).
    Capture(PathBuf),
}

/// The resolved options of a PLC to build.
#[derive(Clone, Debug)]
pub struct Options {
    /// The bus.
    pub bus: BusChoice,
    /// How a Modbus bus exchanges.
    pub link: ModbusOptions,
    /// A scenario for the simulated machine.
    pub scenario: Option<PathBuf>,
    /// The joystick.
    pub joystick: JoystickChoice,
    /// An NC program to run (checked and planned before the PLC is built).
    pub program: Option<PathBuf>,
    /// A directory whose programs (`*.ngc`) the operator may load from the screen instead
    /// (each checked and planned before the PLC is built; those that cannot run are listed).
    pub programs: Option<PathBuf>,
    /// Lay the operator screen's variables over the bus (`HMI_*`, see `hmi`).
    pub hmi: bool,
}

impl Default for Options {
    /// The simulated machine, no scenario, no joystick reader, no program.
    fn default() -> Self {
        Options {
            bus: BusChoice::Sim,
            link: ModbusOptions::default(),
            scenario: None,
            joystick: JoystickChoice::Live(JoystickSpec::None),
            program: None,
            programs: None,
            hmi: false,
        }
    }
}

/// The HID joystick of a built PLC: its reader is started once the PLC runs.
pub struct Joystick {
    /// The source.
    pub spec: JoystickSpec,
    /// Where the reader hands its reports over.
    pub feed: JoystickFeed,
    /// How late reports reach the process image.
    pub probe: LatencyProbe,
    /// Stops the reader.
    pub stop: Arc<AtomicBool>,
}

/// A built PLC with its handles.
pub struct Built {
    /// The configuration it was built from.
    pub setup: Setup,
    /// The PLC.
    pub plc: Plc,
    /// The joystick reader to start, if a live joystick is wanted.
    pub joystick: Option<Joystick>,
    /// The NC programs of the run, if any was given.
    pub library: Option<NcLibrary>,
    /// The programs of `Options::programs` that cannot run on the machine: file and why.
    pub refused: Vec<(String, String)>,
    /// Where the operator screen's commands go, if the screen's variables were laid over the
    /// bus.
    pub hmi: Option<crate::services::hmi::commands::CommandSink>,
    /// The scenario the simulated machine plays, if one was given.
    pub scenario: Option<ScenarioTimes>,
}

/// A scenario's times: how long it says a run of it lasts, and when its last event comes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScenarioTimes {
    /// Its `duration_s`, if it has one.
    pub duration_s: Option<f64>,
    /// When its last event comes (s).
    pub last_event_s: f64,
}

/// Why a PLC could not be built: every problem of the files, or a usage error. The message is
/// ready to show; the command line exits with code 2.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct BuildError(pub String);

impl From<ConfigError> for BuildError {
    fn from(e: ConfigError) -> Self {
        BuildError(e.to_string())
    }
}

/// Why the bus could not be made.
enum BusFailure {
    /// A problem of the configuration or its I/O map: reported with the rest of the checks.
    Config(ConfigError),
    /// The machine could not build its plant from its own sections (`plant`, `kinematics`): the
    /// configuration's check of those sections reports the same problems, once.
    Sections,
    /// Anything else (a usage error): reported alone.
    Other(BuildError),
}

impl From<ConfigError> for BusFailure {
    fn from(e: ConfigError) -> Self {
        BusFailure::Config(e)
    }
}

fn usage(message: impl Into<String>) -> BusFailure {
    BusFailure::Other(BuildError(message.into()))
}

/// The bus `options` ask for, the I/O map it was made over (loaded once, here) and the times of
/// the scenario it plays.
type MadeBus = (Box<dyn Bus>, Option<IoMap>, Option<ScenarioTimes>);

/// The bus `options` ask for (see [`MadeBus`]).
fn make_bus(setup: &Setup, options: &Options) -> Result<MadeBus, BusFailure> {
    let needs_sim = |what: &str| usage(format!("--scenario needs the simulated bus ({what})"));
    // The usage problems first: they need no file read.
    let scenario = options.scenario.as_deref();
    let modbus = matches!(options.bus, BusChoice::Tcp(_) | BusChoice::Serial(..));
    match (modbus, setup.loaded.config.io_map.is_some(), scenario.is_some()) {
        (true, false, _) => return Err(usage("a Modbus bus needs an io_map in the configuration")),
        (true, true, true) => return Err(needs_sim("give it to io-sim instead")),
        (false, has_map, true) if options.bus == BusChoice::None || !has_map => {
            return Err(needs_sim("--bus sim and an io_map in the configuration"));
        }
        _ => {}
    }
    let map = setup.io_map()?;
    let mut times = None;
    let bus: Box<dyn Bus> = match (&options.bus, &map) {
        (BusChoice::Tcp(_) | BusChoice::Serial(..), None) => unreachable!("refused above: no io_map"),
        (BusChoice::Tcp(address), Some(map)) => modbus_bus(setup, map, Transport::Tcp(*address), options)?,
        (BusChoice::Serial(path, baud), Some(map)) => {
            let transport = Transport::Serial {
                path: path.clone(),
                baud: *baud,
            };
            modbus_bus(setup, map, transport, options)?
        }
        (BusChoice::None, Some(map)) => {
            let bus = crate::services::io::dry::DryBus::new(map.clone());
            warn!(
                "--bus none: a dry run of the programs without field I/O: the inputs of the I/O map ({}) hold zero / \
                 false, the outputs go nowhere",
                bus.held_inputs().join(", ")
            );
            Box::new(bus)
        }
        (BusChoice::Sim, Some(_)) => match setup.sim_bus_over(map.clone(), scenario) {
            Ok(bus) => {
                times = scenario.map(|_| ScenarioTimes {
                    duration_s: bus.scenario().duration_s,
                    last_event_s: bus.scenario().last_event_s(),
                });
                Box::new(bus)
            }
            Err(crate::services::sim::BuildError::Plant(_)) => return Err(BusFailure::Sections),
            Err(crate::services::sim::BuildError::Other(e)) => return Err(BusFailure::Config(e)),
        },
        (BusChoice::None | BusChoice::Sim, None) => Box::new(NoBus),
    };
    Ok((bus, map, times))
}

/// A Modbus bus over `map` reached by `transport`; a map too large for the chosen exchange is a
/// usage error (`--exchange`).
fn modbus_bus(setup: &Setup, map: &IoMap, transport: Transport, options: &Options) -> Result<Box<dyn Bus>, BusFailure> {
    let mut link = options.link;
    // The exchange thread one below the cyclic thread (when that asks for real-time priority).
    link.priority = setup.loaded.config.timing.realtime_priority.saturating_sub(1);
    // Every class's cycle hands the outputs over: the fastest says how fresh they are.
    if let Some(fastest) = setup.loaded.config.task_classes.iter().map(|c| c.cycle_us).min() {
        link.fastest_cycle = std::time::Duration::from_micros(u64::from(fastest));
    }
    let bus = ModbusBus::new(map.clone(), transport, link).map_err(|e| usage(format!("--bus: {e}")))?;
    Ok(Box::new(bus))
}

/// Builds a PLC: every problem of the configuration and its I/O map is reported at once.
pub fn build(setup: Setup, options: Options) -> Result<Built, BuildError> {
    // A program that cannot run is refused before anything is built.
    let programs = crate::compose::nc_job::programs(
        &setup,
        options.program.as_deref(),
        options.programs.as_deref(),
        options.hmi,
    )
    .map_err(|e| BuildError(e.message))?;
    // A bus that cannot be made for a problem of the files (the I/O map, the plant section) does
    // not hide the configuration's other problems: they are checked on a stand-in bus.
    let (bus, joystick, scenario, bus_problem) = match make_bus(&setup, &options) {
        Ok((bus, map, scenario)) => {
            let (bus, joystick) = with_joystick(&setup, bus, map.as_ref(), options.joystick)?;
            (bus, joystick, scenario, None)
        }
        Err(BusFailure::Config(e)) => (Box::new(UnknownBus) as Box<dyn Bus>, None, None, Some(e)),
        Err(BusFailure::Sections) => (Box::new(UnknownBus) as Box<dyn Bus>, None, None, None),
        Err(BusFailure::Other(f)) => return Err(f),
    };
    let (bus, hmi) = if options.hmi {
        let (bus, sink) = setup.with_screen(bus);
        (bus, Some(sink))
    } else {
        (bus, None)
    };
    match (setup.plc_with(bus, programs.library.as_ref()), bus_problem) {
        (Ok(plc), None) => Ok(Built {
            setup,
            plc,
            joystick,
            library: programs.library,
            refused: programs.refused,
            hmi,
            scenario,
        }),
        (plc, bus_problem) => {
            let mut problems = match plc {
                Err(ConfigError::Invalid { problems, .. }) => problems,
                Err(other) => return Err(other.into()),
                Ok(_) => Vec::new(),
            };
            let mut reports: Vec<String> = Vec::new();
            // The simulated bus's problems in the configuration's own file (its plant's wiring)
            // join the configuration's list.
            match bus_problem {
                Some(ConfigError::Invalid { file, problems: more }) if file == setup.loaded.origin => {
                    problems.extend(more);
                }
                Some(other) => reports.push(other.to_string()),
                None => {}
            }
            if !problems.is_empty() {
                let own = ConfigError::Invalid {
                    file: setup.loaded.origin.clone(),
                    problems,
                };
                reports.insert(0, own.to_string());
            }
            Err(BuildError(reports.join("\n")))
        }
    }
}

/// Lays the HID joystick over `bus`'s joystick channels, unless the choice is `none` or the I/O
/// map (`map`, as the bus was made over it) binds none.
fn with_joystick(
    setup: &Setup,
    bus: Box<dyn Bus>,
    map: Option<&IoMap>,
    choice: JoystickChoice,
) -> Result<(Box<dyn Bus>, Option<Joystick>), BuildError> {
    let loaded = &setup.loaded;
    let spec = match choice {
        JoystickChoice::Live(JoystickSpec::None) => return Ok((bus, None)),
        JoystickChoice::Live(spec) => spec,
        JoystickChoice::Capture(path) => {
            let states = crate::services::io::hid::load_capture(&path, &loaded.config.joystick)
                .map_err(|e| BuildError(format!("--joystick {e}")))?;
            let Some(map) = map else {
                return Err(BuildError(format!(
                    "--joystick {}: the configuration has no I/O map to bind it to",
                    path.display()
                )));
            };
            let bus = JoystickBus::with_capture(bus, map, states);
            if !bus.binds_anything() {
                return Err(BuildError(format!(
                    "--joystick {}: {} binds no channel of a Joystick module",
                    path.display(),
                    map.origin
                )));
            }
            info!("joystick: playing capture {} on the simulated clock", path.display());
            return Ok((Box::new(bus), None));
        }
    };
    let Some(map) = map else {
        if let JoystickSpec::Path(p) = &spec {
            warn!(
                "--joystick {}: the configuration has no I/O map to bind it to; ignored",
                p.display()
            );
        }
        return Ok((bus, None));
    };
    let (joystick_bus, feed, probe) = JoystickBus::new(bus, map);
    if !joystick_bus.binds_anything() {
        if let JoystickSpec::Path(p) = &spec {
            warn!(
                "--joystick {}: {} binds no channel of a Joystick module; ignored",
                p.display(),
                map.origin
            );
        }
        return Ok((Box::new(joystick_bus), None));
    }
    let joystick = Joystick {
        spec,
        feed,
        probe,
        stop: Arc::new(AtomicBool::new(false)),
    };
    Ok((Box::new(joystick_bus), Some(joystick)))
}

/// A failure with the exit code it means.
#[derive(Debug)]
pub struct Failure {
    /// The exit code: 1 the run failed, 2 a usage or configuration error.
    pub code: u8,
    /// What to tell the user.
    pub message: String,
}

impl Failure {
    /// A usage or configuration error (exit 2): nothing was started.
    pub fn usage(message: impl Into<String>) -> Self {
        Failure {
            code: 2,
            message: message.into(),
        }
    }
    /// The run failed (exit 1).
    pub fn run(message: impl Into<String>) -> Self {
        Failure {
            code: 1,
            message: message.into(),
        }
    }
}

impl From<nc_job::NcFailure> for Failure {
    fn from(e: nc_job::NcFailure) -> Self {
        Failure {
            code: e.code,
            message: e.message,
        }
    }
}

impl From<ConfigError> for Failure {
    fn from(e: ConfigError) -> Self {
        Failure::usage(e.to_string())
    }
}
