//! A configuration with the machine it names resolved: its program types, its sections' checks,
//! its I/O map and digest, the buses made from them and the PLC built on one — and the look
//! through every machine of this build for a hint (which machine has an input, a program, a
//! trace's configuration).

use std::path::Path;

use pkm_api::library::NcLibrary;
use pkm_api::machine::{EmbeddedFile, Machine, Sections};

use super::machines;
use crate::image::Problem;
use crate::program::Registry;
use crate::runtime::bus::{Bus, NoBus};
use crate::runtime::config::{self, ConfigError, LoadedConfig};
use crate::runtime::plc::Plc;
use crate::services::io::map::IoMap;
use crate::services::sim::bus::SimBus;

/// A loaded configuration with the machine it names resolved.
#[derive(Clone, Debug)]
pub struct Setup {
    /// The configuration.
    pub loaded: LoadedConfig,
    /// The machine it runs (`None`: the runtime's self-test programs only).
    pub machine: Option<&'static dyn Machine>,
    /// The tool table NC programs are read with (`None`: the run has none).
    pub tools: Option<ToolTableFile>,
    /// What NC programs start from — the work offsets and G28/G30 positions — where they are
    /// not the configuration's (a parameter file's, a touch-off's, a trace's).
    pub persistent: Option<pkm_nc::params::WorkOffsets>,
    /// The parameter file touch-offs are written to (`None`: they last for the run).
    pub param_file: Option<std::path::PathBuf>,
    /// The parameter file's numbers as it was read (value texts as written): a touch-off's
    /// rewrite keeps those it does not write (LinuxCNC's G92, G59.1 … G59.3, U V W, …).
    pub param_entries: Vec<(usize, String)>,
}

/// A tool table as a run reads it: its file, its text (a trace carries it, so that a replay
/// reads the programs with the same tools) and the table.
#[derive(Clone, Debug)]
pub struct ToolTableFile {
    /// The file, as the user or the configuration named it.
    pub file: String,
    /// Its text.
    pub text: String,
    /// The table.
    pub table: pkm_nc::tools::ToolTable,
}

impl ToolTableFile {
    /// Reads `text` (from `file`); a problem names the file, line and column.
    pub fn parse(file: String, text: String) -> Result<ToolTableFile, String> {
        let table = pkm_nc::tools::ToolTable::parse(&text).map_err(|e| format!("{file}:{e}"))?;
        Ok(ToolTableFile { file, text, table })
    }
}

impl Setup {
    /// Resolves the machine that `loaded` names among the machines of this build.
    pub fn new(loaded: LoadedConfig) -> Result<Setup, ConfigError> {
        let machine = match &loaded.config.machine {
            None => None,
            Some(name) => Some(
                crate::compose::machines::find(name).ok_or_else(|| ConfigError::Invalid {
                    file: loaded.origin.clone(),
                    problems: vec![Problem::new(
                        "machine",
                        format!(
                            "unknown machine \"{}\"; this build has: {}",
                            config::shorten(name),
                            crate::compose::machines::names()
                        ),
                    )],
                })?,
            ),
        };
        Ok(Setup {
            loaded,
            machine,
            tools: None,
            persistent: None,
            param_file: None,
            param_entries: Vec::new(),
        })
    }

    /// What NC programs start from on a machine of `n` coordinates: the parameter file's (or a
    /// touch-off's, a trace's) work offsets and G28/G30 positions, else the configuration's
    /// `nc.work_offsets` and the reference point.
    pub fn persistent(&self, n: usize) -> pkm_nc::params::WorkOffsets {
        self.persistent.unwrap_or_else(|| pkm_nc::params::WorkOffsets {
            origins: self.loaded.config.nc.origins(n),
            homes: [[0.0; 6]; 2],
        })
    }

    /// With the parameter file `path` names (the command line's `--var-file`), else the one the
    /// configuration's `nc.var_file` names (relative to its directory), else none: its values
    /// when it exists (else the configuration's until the first touch-off writes it). A file
    /// that cannot be read or parsed is a usage error (exit 2) naming it.
    pub fn with_param_file(mut self, path: Option<&Path>) -> Result<Setup, super::Failure> {
        let Some(file) = self.nc_file(path, self.loaded.config.nc.var_file.as_deref()) else {
            return Ok(self);
        };
        let name = file.display().to_string();
        // A touch-off replaces the file (a new one renamed over it): over a symbolic link that
        // would put a file in the link's place and leave its target as it was.
        if std::fs::symlink_metadata(&file).is_ok_and(|m| m.file_type().is_symlink()) {
            return Err(super::Failure::usage(format!(
                "{name}: is a symbolic link: a touch-off rewrites the parameter file, and would replace the link \
                 with a file of its own; name the file itself"
            )));
        }
        match crate::runtime::files::read_text(&file, crate::runtime::files::MAX_TEXT_BYTES) {
            Ok(text) => {
                let values = pkm_nc::params::parse(&text).map_err(|e| super::Failure::usage(format!("{name}:{e}")))?;
                self.persistent = Some(values);
                self.param_entries = pkm_nc::params::entries(&text);
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => {
                return Err(super::Failure::usage(format!(
                    "{name}: cannot read the parameter file: {e}"
                )));
            }
        }
        self.param_file = Some(file);
        Ok(self)
    }

    /// The NC file `given` names (the command line's), else the one the configuration names as
    /// `configured` (relative to its directory), else none.
    fn nc_file(&self, given: Option<&Path>, configured: Option<&str>) -> Option<std::path::PathBuf> {
        match (given, configured) {
            (Some(p), _) => Some(p.to_path_buf()),
            (None, Some(name)) => Some(match &self.loaded.dir {
                Some(dir) => dir.join(name),
                None => std::path::PathBuf::from(name),
            }),
            (None, None) => None,
        }
    }

    /// What keeps a touch-off's work offsets for a machine of `n` coordinates: writes the
    /// parameter file so that a crash or a power cut leaves the old one or the new one, whole
    /// ([`crate::runtime::files::replace_durably`]), with every number of the file as it was
    /// read that this interpreter does not write; `None` without a parameter file.
    pub fn keeper(&self, n: usize) -> Option<crate::services::hmi::jobs::Keep> {
        let path = self.param_file.clone()?;
        let kept = self.param_entries.clone();
        Some(std::sync::Arc::new(move |offsets: &pkm_nc::params::WorkOffsets| {
            let text = pkm_nc::params::format_keeping(offsets, n, &kept);
            crate::runtime::files::replace_durably(&path, &text)
                .map_err(|e| format!("{}: cannot write the parameter file: {e}", path.display()))
        }))
    }

    /// With the tool table `path` names (the command line's `--tool-table`), else the one the
    /// configuration's `nc.tool_table` names (relative to the configuration's directory), else
    /// none. A file that cannot be read or parsed is a usage error (exit 2) naming it.
    pub fn with_tool_table(mut self, path: Option<&Path>) -> Result<Setup, super::Failure> {
        let Some(file) = self.nc_file(path, self.loaded.config.nc.tool_table.as_deref()) else {
            return Ok(self);
        };
        let name = file.display().to_string();
        let text = crate::runtime::files::read_text(&file, crate::runtime::files::MAX_TEXT_BYTES)
            .map_err(|e| super::Failure::usage(format!("{name}: cannot read the tool table: {e}")))?;
        self.tools = Some(ToolTableFile::parse(name, text).map_err(super::Failure::usage)?);
        Ok(self)
    }

    /// Loads `path` (or the built-in configuration) and resolves its machine.
    pub fn load(path: Option<&Path>) -> Result<Setup, ConfigError> {
        Setup::new(config::load(path)?)
    }

    /// The configuration's file name, for messages.
    pub fn origin(&self) -> &str {
        &self.loaded.origin
    }

    /// The machine's sections of the configuration.
    pub fn sections(&self) -> Sections<'_> {
        Sections {
            kinematics: self.loaded.config.kinematics.as_ref(),
            plant: self.loaded.config.plant.as_ref(),
        }
    }

    /// The program types this configuration can name: the runtime's self-test programs and the
    /// machine's.
    pub fn registry(&self) -> Registry {
        let mut registry = Registry::new();
        crate::compose::selftest::register(&mut registry);
        for info in self.machine.map(|m| m.programs()).unwrap_or_default() {
            registry.register(*info);
        }
        registry
    }

    /// Adds to each "unknown program" problem the machine that brings that program, where another
    /// machine of this build does: the usual cause is a configuration copied from another machine,
    /// or a missing or different `"machine"`.
    fn hint_other_machines(&self, problems: &mut [Problem]) {
        for (ci, tc) in self.loaded.config.task_classes.iter().enumerate() {
            for (pi, entry) in tc.programs.iter().enumerate() {
                let at = format!("task_classes[{ci}].programs[{pi}].program");
                let Some(owner) = machines::owner_of(&entry.program) else {
                    continue;
                };
                if self.machine.is_some_and(|m| m.name() == owner.name()) {
                    continue;
                }
                let runs = match self.machine {
                    Some(m) => format!("this configuration runs machine \"{}\"", m.name()),
                    None => "this configuration names no machine".to_string(),
                };
                for problem in problems.iter_mut().filter(|p| p.at == at) {
                    problem.message.push_str(&format!(
                        " (\"{}\" is a program of machine \"{}\"; {runs}: set \"machine\": \"{}\")",
                        entry.program,
                        owner.name(),
                        owner.name()
                    ));
                }
            }
        }
    }

    /// The problems of the machine's sections (`kinematics`, `plant`); without a machine, those
    /// sections have nobody to check them and are refused.
    pub fn section_problems(&self) -> Vec<Problem> {
        match self.machine {
            Some(m) => {
                let mut problems = m.check(&self.sections());
                // What must hold between the sections and the programs' parameters, and the NC
                // section against the machine's coordinates (when its own sections and
                // parameters let it say what they are).
                if problems.is_empty() {
                    problems.extend(m.cross_check(&self.loaded.json));
                }
                if problems.is_empty()
                    && let Ok(motion) = m.motion(&self.loaded.json)
                {
                    problems.extend(self.loaded.config.nc.check(motion.axes));
                }
                problems
            }
            None => {
                let sections = self.sections();
                [("kinematics", sections.kinematics), ("plant", sections.plant)]
                    .into_iter()
                    .filter(|(_, s)| s.is_some())
                    .map(|(at, _)| {
                        Problem::new(
                            at,
                            format!(
                                "the {at} section belongs to a machine, and the configuration names none: \
                                 add \"machine\" ({})",
                                crate::compose::machines::names()
                            ),
                        )
                    })
                    .collect()
            }
        }
    }

    /// The machine's built-in I/O map, which the built-in configuration names.
    pub fn embedded_io_map(&self) -> Option<EmbeddedFile> {
        self.machine.map(|m| m.default_io_map())
    }

    /// Loads and validates the I/O map; `None` when the configuration names none.
    pub fn io_map(&self) -> Result<Option<IoMap>, ConfigError> {
        IoMap::load(&self.loaded, self.embedded_io_map())
    }

    /// The digest of the configuration with its I/O map (traces carry it).
    pub fn digest(&self) -> Result<String, ConfigError> {
        crate::services::trace::config_digest(&self.loaded, self.embedded_io_map())
    }

    /// The simulated machine behind the I/O map, with `scenario` if given.
    pub fn sim_bus(&self, scenario: Option<&Path>) -> Result<SimBus, ConfigError> {
        Ok(self.sim_bus_over(self.io_map()?, scenario)?)
    }

    /// The simulated machine behind `map`, the configuration's I/O map as loaded.
    pub(super) fn sim_bus_over(
        &self,
        map: Option<IoMap>,
        scenario: Option<&Path>,
    ) -> Result<SimBus, crate::services::sim::BuildError> {
        let invalid = |at: &str, message: &str| {
            crate::services::sim::BuildError::Other(ConfigError::Invalid {
                file: self.loaded.origin.clone(),
                problems: vec![Problem::new(at, message)],
            })
        };
        let Some(map) = map else {
            return Err(invalid("io_map", "the simulated bus needs an I/O map"));
        };
        let Some(machine) = self.machine else {
            return Err(invalid(
                "machine",
                "the simulated bus needs a machine to simulate: name one with \"machine\"",
            ));
        };
        let hint = |name: &str| hint(&with_input(name));
        crate::services::sim::build(&self.loaded, machine, map, scenario, &hint)
    }

    /// Lays the operator screen's variables (`HMI_*`) over `bus`, latched by the fastest class:
    /// the screen's STOP reaches the fast interlock as the panel's does.
    pub fn with_screen(&self, bus: Box<dyn Bus>) -> (Box<dyn Bus>, crate::services::hmi::commands::CommandSink) {
        let classes = &self.loaded.config.task_classes;
        let fastest = (0..classes.len()).min_by_key(|&c| classes[c].cycle_us).unwrap_or(0);
        let (bus, sink) = crate::services::hmi::commands::HmiBus::new(bus, fastest, self.stop_lockout_ns());
        (Box::new(bus), sink)
    }

    /// The longest STOP lockout of the configuration's programs (`params.stop_lockout_ms`, the
    /// main programs' parameter; 500 ms where none sets it): after a STOP press is taken, the
    /// button is ignored this long, so an acknowledgement must come later.
    fn stop_lockout_ns(&self) -> u64 {
        const DEFAULT_MS: u64 = 500;
        let programs = self.loaded.json["task_classes"]
            .as_array()
            .into_iter()
            .flatten()
            .filter_map(|c| c["programs"].as_array())
            .flatten();
        let ms = programs
            .filter_map(|p| p["params"]["stop_lockout_ms"].as_f64())
            .fold(DEFAULT_MS as f64, f64::max);
        (ms * 1e6) as u64
    }

    /// A bus that only declares the I/O map's variables (inputs written by the bus, outputs read
    /// by it) and exchanges nothing: replay feeds the recorded inputs itself.
    pub fn declaring_bus(&self) -> Result<Box<dyn Bus>, ConfigError> {
        Ok(match self.io_map()? {
            Some(map) => Box::new(crate::services::io::dry::DryBus::new(map)),
            None => Box::new(NoBus),
        })
    }

    /// Builds the PLC on `bus`: declares every program's variables and checks the configuration
    /// as a whole, the machine's sections included.
    pub fn plc(&self, bus: Box<dyn Bus>) -> Result<Plc, ConfigError> {
        self.plc_with(bus, None)
    }

    /// [`Setup::plc`] with NC programs for the machine's programs to run.
    pub fn plc_with(&self, bus: Box<dyn Bus>, library: Option<&NcLibrary>) -> Result<Plc, ConfigError> {
        let plc = Plc::build_with(&self.loaded.config, &self.registry(), bus, library);
        let mut problems = self.section_problems();
        match plc {
            Ok(plc) if problems.is_empty() => Ok(plc),
            plc => {
                let mut build_problems = plc.err().unwrap_or_default();
                self.hint_other_machines(&mut build_problems);
                problems.splice(0..0, build_problems);
                Err(ConfigError::Invalid {
                    file: self.loaded.origin.clone(),
                    problems,
                })
            }
        }
    }
}

/// The configured machine, drawn on the screen by its kinematics at its measured joints.
impl crate::services::hmi::mechanism::Drawable for Setup {
    fn drawing(&self) -> Option<crate::services::hmi::mechanism::Drawing> {
        use pkm_api::machine::Home;
        use pkm_kinematics::frame::{Home as FrameHome, MachineFrame};
        let motion = self.machine?.motion(&self.loaded.json).ok()?;
        let config = pkm_kinematics::KinematicsConfig::from_section(self.loaded.config.kinematics.as_ref()).ok()?;
        let model = pkm_kinematics::Machine::from_name(motion.model)?;
        // The machine frame's origin (the home pose) in the mechanism's: the drawing is moved
        // by it, so that it stands where the tool's positions and the paths are.
        let home = match &motion.home {
            Home::Joints(q) => FrameHome::Joints(q),
            Home::Pose(x) => FrameHome::Pose(x),
        };
        let frame = MachineFrame::new(config.build(model), home).ok()?;
        let mut origin = [0.0; 3];
        for (key, at) in frame.kinematics().pose_keys().iter().zip(frame.home_pose()) {
            if let Some(c) = ["x", "y", "z"].iter().position(|k| k == key) {
                origin[c] = *at;
            }
        }
        Some(crate::services::hmi::mechanism::Drawing {
            kinematics: config.build(model),
            joints: motion.joint_vars,
            origin,
        })
    }
}

/// Machine `name` with its own configuration (as [`machines::configuration`] loads it), if this build has
/// it and the configuration loads: for the hints that look through every machine.
pub fn of_machine(name: &str) -> Option<Setup> {
    machines::configuration(name)
        .and_then(Result::ok)
        .and_then(|loaded| Setup::new(loaded).ok())
}

/// The machine whose configuration (as [`machines::configuration`] loads it) has the digest `digest` — a
/// trace's `config_digest` — if one has.
pub fn with_digest(digest: &str) -> Option<&'static str> {
    machines::BUILTIN.iter().map(|m| m.name()).find(|name| {
        of_machine(name)
            .and_then(|s| s.digest().ok())
            .is_some_and(|d| d == digest)
    })
}

/// The machines whose own I/O map binds an input variable `name` (for a hint when a scenario
/// names an input the configured machine has not).
pub fn with_input(name: &str) -> Vec<&'static str> {
    machines::BUILTIN
        .iter()
        .map(|m| m.name())
        .filter(|machine| {
            of_machine(machine)
                .and_then(|setup| setup.io_map().ok().flatten())
                .is_some_and(|map| {
                    map.bindings
                        .iter()
                        .any(|b| b.variable == name && b.direction == crate::services::io::catalogue::Direction::Input)
                })
        })
        .collect()
}

/// A hint that names the machines in `names` (`--machine NAME`), or nothing without any.
pub fn hint(names: &[&str]) -> String {
    match names {
        [] => String::new(),
        [one] => format!(" (machine {one} has it: --machine {one})"),
        more => format!(" (machines {} have it: --machine NAME)", more.join(", ")),
    }
}
