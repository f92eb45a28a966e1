//! config.json: strict parsing, and the checks that need no program knowledge.
//!
//! Every error names the file, the JSON path inside it and what was expected. Parsing stops at the
//! first malformed element (serde cannot go on), but semantic checks run over the whole
//! configuration and report every problem at once.

pub mod identification;
pub mod joystick;

use std::fmt;
use std::path::{Path, PathBuf};

use pkm_api::ranges::{self, Range};
use serde::Deserialize;

use crate::image::Problem;

/// The configuration built into the binary: the repository's top-level config.json.
pub const BUILTIN_CONFIG: &str = include_str!("../../../config.json");

/// Shortest cycle time accepted (µs).
pub const MIN_CYCLE_US: u32 = 200;
/// Longest cycle time accepted (µs).
pub const MAX_CYCLE_US: u32 = 10_000_000;
/// A task class's tolerance is at least its cycle time divided by this.
pub const MIN_TOLERANCE_DIVISOR: u32 = 10;

/// The whole configuration file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// The machine the configuration runs (`trijoint`): it brings the programs, the check of the
    /// `kinematics` and `plant` sections, the default I/O map and the simulated plant. Without
    /// one, only the runtime's own (self-test) programs can run.
    #[serde(default)]
    pub machine: Option<String>,
    /// The task classes, each with its programs.
    pub task_classes: Vec<TaskClassConfig>,
    /// How real time is kept.
    #[serde(default)]
    pub timing: TimingConfig,
    /// The I/O map file, relative to this file's directory (the built-in configuration uses the
    /// built-in io-map/trijoint.json). Without it there is no field I/O.
    #[serde(default)]
    pub io_map: Option<String>,
    /// The simulated machine (used with `--bus sim`); checked by the machine.
    #[serde(default)]
    pub plant: Option<serde_json::Value>,
    /// Kinematic parameters of the machine models; checked by the machine, defaults from the
    /// spec.
    #[serde(default)]
    pub kinematics: Option<serde_json::Value>,
    /// How the HID joystick's events map to the operator's commands (`--joystick`).
    #[serde(default)]
    pub joystick: joystick::JoystickMapping,
    /// NC programs: work offsets and the world axes' limits.
    #[serde(default)]
    pub nc: NcConfig,
    /// The machine's nameplate (OPC UA's Machinery `Identification`).
    #[serde(default)]
    pub identification: identification::Identification,
}

/// The work coordinate systems of NC programs, in order (G54 is the first).
pub const WORK_SYSTEMS: [&str; 6] = ["G54", "G55", "G56", "G57", "G58", "G59"];

/// The `nc` section: what NC programs need besides the machine.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NcConfig {
    /// The origins of work coordinate systems in the machine frame (one value per coordinate of
    /// the machine: x y z, and a b c where it has them); a system left out has its origin at the
    /// reference point.
    #[serde(default)]
    pub work_offsets: std::collections::BTreeMap<String, Vec<f64>>,
    /// Speed per world axis (mm/s, degrees/s), one per coordinate; left out: only the joints'
    /// limits bound the tool.
    #[serde(default)]
    pub axis_speed: Option<Vec<f64>>,
    /// Acceleration per world axis (mm/s², degrees/s²), one per coordinate.
    #[serde(default)]
    pub axis_accel: Option<Vec<f64>>,
    /// The block-delete switch: on, a program's lines that start with `/` are skipped; off (the
    /// default, as LinuxCNC's), they run.
    #[serde(default)]
    pub block_delete: bool,
    /// The tool table, in LinuxCNC's `tool.tbl` format, relative to this file's directory
    /// (`--tool-table` overrides it); without one, T, M6 and G43 H are refused.
    #[serde(default)]
    pub tool_table: Option<String>,
    /// The parameter file (LinuxCNC's `.var` format) that keeps the work offsets and G28/G30
    /// positions across runs, relative to this file's directory (`--var-file` overrides it);
    /// a touch-off on the screen writes it.
    #[serde(default)]
    pub var_file: Option<String>,
    /// The share of each joint's and world axis' acceleration a program's plan uses (1 by
    /// default): a machine whose drives follow the planned (trapezoidal) speed profile within
    /// the contour tolerance only at less sets it lower.
    #[serde(default)]
    pub accel_share: Option<f64>,
    /// The most moves and other actions one program may make (1 000 000 by default): a
    /// program that makes more is refused at the line where it passes the bound.
    #[serde(default)]
    pub max_moves: Option<u64>,
    /// The most memory one program and its plan may take (MiB, 2048 by default), as counted
    /// from its moves and its path's length while it is read.
    #[serde(default)]
    pub max_plan_mib: Option<u64>,
    /// The longest a program's reading, check and plan may take (s, 30 by default): a job of
    /// the screen, a program at start, `nc check`.
    #[serde(default)]
    pub max_planning_s: Option<f64>,
    /// The longest a program may run as planned, its motion and dwells (hours, 12 by
    /// default): a program planned to take longer is refused with its planned time and the
    /// line that takes longest (a feed or a dwell mistyped, as a rule).
    #[serde(default)]
    pub max_duration_h: Option<f64>,
    /// Laser mode: the spindle words drive a laser's beam (`LASER_POWER`) instead of a spindle.
    #[serde(default)]
    pub laser: Option<LaserConfig>,
}

/// Laser mode (`nc.laser`), as grbl's: `S` is the beam's power, 0 … `s_max`; M3 keeps it
/// constant, M4 scales it with the tool's speed along the path over the programmed feed, so
/// that corners and ramps do not burn; off during rapids, with M5, in every state but AUTO and at
/// once on STOP.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LaserConfig {
    /// The S word of full power (`LASER_POWER` 1).
    pub s_max: f64,
}

/// How long a program may run as planned unless `nc.max_duration_h` says otherwise (hours).
pub const DEFAULT_MAX_DURATION_H: f64 = 12.0;

/// How long a program's preparation may take unless `nc.max_planning_s` says otherwise (s).
pub const DEFAULT_MAX_PLANNING_S: f64 = 30.0;

impl NcConfig {
    /// What one program may cost (`max_moves`, `max_plan_mib`; the defaults without them).
    pub fn bounds(&self) -> pkm_nc::budget::Bounds {
        let default = pkm_nc::budget::Bounds::default();
        pkm_nc::budget::Bounds {
            max_moves: self
                .max_moves
                .and_then(|m| usize::try_from(m).ok())
                .unwrap_or(default.max_moves),
            max_bytes: self
                .max_plan_mib
                .map_or(default.max_bytes, |m| m.saturating_mul(1 << 20)),
        }
    }

    /// How long a program's preparation may take (`max_planning_s`, else
    /// [`DEFAULT_MAX_PLANNING_S`]).
    pub fn max_planning(&self) -> std::time::Duration {
        std::time::Duration::from_secs_f64(
            self.max_planning_s
                .filter(|s| ranges::NC_MAX_PLANNING_S.contains(*s))
                .unwrap_or(DEFAULT_MAX_PLANNING_S),
        )
    }

    /// How long a program may run as planned (`max_duration_h`, else
    /// [`DEFAULT_MAX_DURATION_H`]), in seconds.
    pub fn max_duration_s(&self) -> f64 {
        self.max_duration_h
            .filter(|h| ranges::NC_MAX_DURATION_H.contains(*h))
            .unwrap_or(DEFAULT_MAX_DURATION_H)
            * 3600.0
    }

    /// The share of the accelerations a program's plan uses (`accel_share`, 1 without it).
    pub fn accel_share(&self) -> f64 {
        self.accel_share.unwrap_or(1.0)
    }

    /// The origin of each work coordinate system, G54 first (the reference point where the
    /// section gives none); `n` values each.
    pub fn origins(&self, n: usize) -> [[f64; 6]; 6] {
        let mut origins = [[0.0; 6]; 6];
        for (i, name) in WORK_SYSTEMS.iter().enumerate() {
            if let Some(offset) = self.work_offsets.get(*name) {
                for (o, v) in origins[i].iter_mut().zip(offset).take(n) {
                    *o = *v;
                }
            }
        }
        origins
    }

    /// Checks the section for a machine whose world coordinates are `keys`; problems have their
    /// path below `nc`.
    pub fn check(&self, keys: &[&str]) -> Vec<Problem> {
        let n = keys.len();
        let mut problems = Vec::new();
        let names = keys.iter().map(|k| k.to_uppercase()).collect::<Vec<_>>().join(" ");
        // One value per coordinate, each within its range (mm or degrees by the coordinate).
        let values = |problems: &mut Vec<Problem>, at: String, v: &[f64], linear: Range, angular: Range| {
            if v.len() != n {
                problems.push(Problem {
                    at: at.clone(),
                    message: format!(
                        "one value per coordinate of the machine ({names}): {n}, got {}",
                        v.len()
                    ),
                });
            }
            for (i, (x, key)) in v.iter().zip(keys).enumerate() {
                let range = if ranges::is_rotation(key) { angular } else { linear };
                ranges::check_into(problems, format!("{at}[{i}]"), *x, &range);
            }
        };
        for (system, offset) in &self.work_offsets {
            let at = format!("nc.work_offsets.{}", shorten(system));
            if WORK_SYSTEMS.contains(&system.as_str()) {
                values(&mut problems, at, offset, ranges::POSITION_MM, ranges::ANGLE_DEG);
            } else {
                problems.push(Problem {
                    at,
                    message: format!("a work coordinate system is one of {}", WORK_SYSTEMS.join(", ")),
                });
            }
        }
        if let Some(v) = &self.axis_speed {
            values(
                &mut problems,
                "nc.axis_speed".into(),
                v,
                ranges::SPEED_MM_S,
                ranges::ANGULAR_SPEED_DEG_S,
            );
        }
        if let Some(v) = &self.axis_accel {
            values(
                &mut problems,
                "nc.axis_accel".into(),
                v,
                ranges::ACCEL_MM_S2,
                ranges::ACCEL_MM_S2,
            );
        }
        if let Some(share) = self.accel_share {
            ranges::check_into(&mut problems, "nc.accel_share", share, &ranges::ACCEL_SHARE);
        }
        if let Some(moves) = self.max_moves {
            ranges::check_into(&mut problems, "nc.max_moves", moves as f64, &ranges::NC_MAX_MOVES);
        }
        if let Some(mib) = self.max_plan_mib {
            ranges::check_into(&mut problems, "nc.max_plan_mib", mib as f64, &ranges::NC_MAX_PLAN_MIB);
        }
        if let Some(s) = self.max_planning_s {
            ranges::check_into(&mut problems, "nc.max_planning_s", s, &ranges::NC_MAX_PLANNING_S);
        }
        if let Some(h) = self.max_duration_h {
            ranges::check_into(&mut problems, "nc.max_duration_h", h, &ranges::NC_MAX_DURATION_H);
        }
        if let Some(laser) = self.laser {
            ranges::check_into(&mut problems, "nc.laser.s_max", laser.s_max, &ranges::LASER_S_MAX);
        }
        problems
    }
}

/// One task class (B&R: a "cyclic" task class).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TaskClassConfig {
    /// Unique name, used in logs, summaries and traces.
    pub name: String,
    /// Cycle time in microseconds.
    pub cycle_us: u32,
    /// How far past its deadline a cycle may end before it is a cycle time violation (µs).
    pub tolerance_us: u32,
    /// 1 is the highest. Classes due at the same instant run in priority order; a faster class
    /// must have a higher priority than a slower one.
    pub priority: u8,
    /// What a cycle time violation does.
    #[serde(default)]
    pub on_violation: Reaction,
    /// The programs, run in this order in every cycle.
    pub programs: Vec<ProgramEntry>,
}

/// One program instance in a task class.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProgramEntry {
    /// The program type's name.
    pub program: String,
    /// Program-specific parameters, checked by the program itself.
    #[serde(default)]
    pub params: Option<serde_json::Value>,
}

/// What a cycle time violation does.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Reaction {
    /// Count it and log a warning.
    Log,
    /// Count it, log it, and tell the application, which enters ERROR ("cycle time violation"),
    /// as a B&R controller goes to service mode.
    #[default]
    Error,
}

/// How real time is kept.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimingConfig {
    /// The timer that wakes the cyclic thread.
    #[serde(default)]
    pub source: TimeSourceKind,
    /// SCHED_FIFO priority for the cyclic thread (1..=99); 0 does not ask for real-time priority.
    #[serde(default = "default_rt_priority")]
    pub realtime_priority: u8,
    /// Lock the process's memory (mlockall) so that page faults cannot delay a cycle.
    #[serde(default = "default_true")]
    pub lock_memory: bool,
    /// Wake this many µs before each release and busy-wait to it (0: no spinning). Cuts wake-up
    /// latency at the cost of that much CPU time per release.
    #[serde(default)]
    pub spin_us: u32,
}

fn default_rt_priority() -> u8 {
    80
}
fn default_true() -> bool {
    true
}

impl Default for TimingConfig {
    fn default() -> Self {
        TimingConfig {
            source: TimeSourceKind::Auto,
            realtime_priority: default_rt_priority(),
            lock_memory: true,
            spin_us: 0,
        }
    }
}

/// The timers the real-time scheduler can wait on (see the README's measurements).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TimeSourceKind {
    /// The best measured on Linux: `nanosleep`.
    #[default]
    Auto,
    /// tokio's timer (`sleep_until` on absolute deadlines, as `tokio::time::interval` uses):
    /// 1 ms granularity.
    Tokio,
    /// A timerfd armed with an absolute deadline, registered with tokio's `AsyncFd`.
    Timerfd,
    /// `clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)` on the dedicated cyclic thread.
    Nanosleep,
}

impl TimeSourceKind {
    /// The concrete source `auto` stands for.
    pub fn resolve(self) -> TimeSourceKind {
        match self {
            TimeSourceKind::Auto => TimeSourceKind::Nanosleep,
            other => other,
        }
    }

    /// The name used in config.json and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            TimeSourceKind::Auto => "auto",
            TimeSourceKind::Tokio => "tokio",
            TimeSourceKind::Timerfd => "timerfd",
            TimeSourceKind::Nanosleep => "nanosleep",
        }
    }
}

/// A configuration and where it came from.
#[derive(Clone, Debug)]
pub struct LoadedConfig {
    /// The file's name as the user gave it, or `<built-in config.json>`.
    pub origin: String,
    /// The parsed configuration.
    pub config: Config,
    /// The directory that relative paths in it are relative to (`None`: the built-in one).
    pub dir: Option<PathBuf>,
    /// The configuration as JSON (for digests).
    pub json: serde_json::Value,
}

/// Why a configuration was refused.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("{file}: cannot read the file: {source}")]
    Read {
        /// The file.
        file: String,
        /// The OS error.
        source: std::io::Error,
    },
    /// The file is not well-formed JSON.
    #[error("{file}: line {line}, column {column}: {message}")]
    Syntax {
        /// The file.
        file: String,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
        /// What the JSON parser says.
        message: String,
    },
    /// One or more elements are missing, unknown, of the wrong type or out of range.
    #[error("{}", Problems { file, problems })]
    Invalid {
        /// The file.
        file: String,
        /// Every problem found, in document order.
        problems: Vec<Problem>,
    },
}

impl ConfigError {
    /// The problems of an `Invalid` error (empty for the others).
    pub fn problems(&self) -> &[Problem] {
        match self {
            ConfigError::Invalid { problems, .. } => problems,
            _ => &[],
        }
    }
}

struct Problems<'a> {
    file: &'a str,
    problems: &'a [Problem],
}

impl fmt::Display for Problems<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.problems {
            [one] => write!(f, "{}: at {}: {}", self.file, one.at, one.message),
            many => {
                write!(f, "{}: {} problems:", self.file, many.len())?;
                for p in many {
                    write!(f, "\n  at {}: {}", p.at, p.message)?;
                }
                Ok(())
            }
        }
    }
}

/// Loads `path`, or the built-in configuration when `path` is `None`.
pub fn load(path: Option<&Path>) -> Result<LoadedConfig, ConfigError> {
    match path {
        Some(p) => {
            let origin = p.display().to_string();
            let text =
                crate::runtime::files::read_text(p, crate::runtime::files::MAX_TEXT_BYTES).map_err(|source| {
                    ConfigError::Read {
                        file: origin.clone(),
                        source,
                    }
                })?;
            let mut loaded = parse(&text, &origin)?;
            loaded.dir = Some(p.parent().map(Path::to_path_buf).unwrap_or_default());
            Ok(loaded)
        }
        None => parse(BUILTIN_CONFIG, "<built-in config.json>"),
    }
}

/// The configuration file to use when none is given: `./config.json` if there is one.
pub fn default_path() -> Option<PathBuf> {
    let p = PathBuf::from("config.json");
    p.is_file().then_some(p)
}

/// Parses a configuration text strictly; `origin` names it in errors.
pub fn parse(text: &str, origin: &str) -> Result<LoadedConfig, ConfigError> {
    let json = parse_value(text, origin)?;
    let config: Config = from_json(&json, origin)?;
    Ok(LoadedConfig {
        origin: origin.to_string(),
        config,
        dir: None,
        json,
    })
}

/// Parses any strict JSON document (no duplicate keys, structs from objects only: see
/// [`crate::strict_json`]), turning serde's errors into [`ConfigError`]s that name the file, the
/// JSON path and what was expected.
pub fn parse_strict<T: serde::de::DeserializeOwned>(text: &str, origin: &str) -> Result<T, ConfigError> {
    from_json(&parse_value(text, origin)?, origin)
}

/// Reads a JSON document into a value, refusing duplicate keys.
fn parse_value(text: &str, origin: &str) -> Result<serde_json::Value, ConfigError> {
    let mut de = serde_json::Deserializer::from_str(text);
    let result: Result<serde_json::Value, (String, serde_json::Error)> =
        serde_path_to_error::deserialize::<_, crate::strict_json::Unique>(&mut de)
            .map(|u| u.0)
            .map_err(|e| (e.path().to_string(), e.into_inner()))
            .and_then(|v| de.end().map(|()| v).map_err(|e| (".".to_string(), e)));
    result.map_err(|(path, inner)| json_error(origin, &path, &inner))
}

/// Takes a `T` from a parsed document.
fn from_json<T: serde::de::DeserializeOwned>(json: &serde_json::Value, origin: &str) -> Result<T, ConfigError> {
    crate::strict_json::from_value(json).map_err(|e| json_error(origin, &e.path().to_string(), e.inner()))
}

fn json_error(origin: &str, path: &str, inner: &serde_json::Error) -> ConfigError {
    let message = shorten(&strip_position(&inner.to_string())).into_owned();
    match inner.classify() {
        // A value's problems (a duplicate key too) have a path; the text's have a position.
        serde_json::error::Category::Syntax | serde_json::error::Category::Eof | serde_json::error::Category::Io
            if inner.line() > 0 =>
        {
            ConfigError::Syntax {
                file: origin.to_string(),
                line: inner.line(),
                column: inner.column(),
                message,
            }
        }
        _ => ConfigError::Invalid {
            file: origin.to_string(),
            problems: vec![Problem {
                at: display_path(path),
                message,
            }],
        },
    }
}

pub use pkm_api::strict_json::shorten;

/// serde_json appends " at line L column C" to its messages; the path says more, so drop it.
fn strip_position(message: &str) -> String {
    match message.rfind(" at line ") {
        Some(i) => message[..i].to_string(),
        None => message.to_string(),
    }
}

fn display_path(path: &str) -> String {
    if path == "." {
        "(top level)".to_string()
    } else {
        path.to_string()
    }
}

/// The checks of the configuration that need no knowledge of programs or the I/O map.
///
/// Long, and kept whole: a list of independent checks of a few lines each, in the order of the
/// file, so that the report follows the file.
pub fn check(config: &Config) -> Vec<Problem> {
    let mut issues = Vec::new();
    let mut push = |at: String, message: String| issues.push(Problem { at, message });
    if config.task_classes.is_empty() {
        push("task_classes".into(), "at least one task class is required".into());
    }
    for (i, tc) in config.task_classes.iter().enumerate() {
        let at = format!("task_classes[{i}]");
        if tc.name.is_empty()
            || !tc
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
        {
            push(
                format!("{at}.name"),
                format!(
                    "task class name \"{}\" is not valid: use letters, digits, '_' and '-'",
                    tc.name
                ),
            );
        }
        if let Some(j) = config.task_classes[..i].iter().position(|o| o.name == tc.name) {
            push(
                format!("{at}.name"),
                format!("task class name \"{}\" is already used by task_classes[{j}]", tc.name),
            );
        }
        if !(MIN_CYCLE_US..=MAX_CYCLE_US).contains(&tc.cycle_us) {
            push(
                format!("{at}.cycle_us"),
                format!(
                    "cycle time must be between {MIN_CYCLE_US} and {MAX_CYCLE_US} µs, got {}",
                    tc.cycle_us
                ),
            );
        }
        // (A cycle out of range is one problem, not two.)
        if (MIN_CYCLE_US..=MAX_CYCLE_US).contains(&tc.cycle_us) && tc.tolerance_us > tc.cycle_us {
            push(
                format!("{at}.tolerance_us"),
                format!(
                    "tolerance must be at most the cycle time ({} µs): a cycle that starts later than \
                     that has missed its slot, got {}",
                    tc.cycle_us, tc.tolerance_us
                ),
            );
        }
        if (MIN_CYCLE_US..=MAX_CYCLE_US).contains(&tc.cycle_us) && tc.tolerance_us < tc.cycle_us / MIN_TOLERANCE_DIVISOR
        {
            push(
                format!("{at}.tolerance_us"),
                format!(
                    "tolerance must be at least a tenth of the cycle time ({} µs): below it every wake-up of a \
                     busy operating system is a cycle time violation, got {}",
                    tc.cycle_us / MIN_TOLERANCE_DIVISOR,
                    tc.tolerance_us
                ),
            );
        }
        if tc.priority == 0 {
            push(
                format!("{at}.priority"),
                "priority must be 1 (highest) or more, got 0".into(),
            );
        }
        if let Some(j) = config.task_classes[..i].iter().position(|o| o.priority == tc.priority) {
            push(
                format!("{at}.priority"),
                format!(
                    "priority {} is already used by task class \"{}\" (task_classes[{j}]); priorities are unique",
                    tc.priority, config.task_classes[j].name
                ),
            );
        }
        for other in &config.task_classes[..i] {
            let (fast, slow) = if tc.cycle_us < other.cycle_us {
                (tc, other)
            } else {
                (other, tc)
            };
            if fast.cycle_us != slow.cycle_us && fast.priority > slow.priority {
                push(
                    format!("{at}.priority"),
                    format!(
                        "task class \"{}\" ({} µs, priority {}) is faster than \"{}\" ({} µs, priority {}) \
                         but has the lower priority; a faster class must have the higher priority (a smaller number)",
                        fast.name, fast.cycle_us, fast.priority, slow.name, slow.cycle_us, slow.priority
                    ),
                );
            }
        }
        for (k, entry) in tc.programs.iter().enumerate() {
            let first = config.task_classes[..=i].iter().enumerate().find_map(|(ci, c)| {
                let upto = if ci == i { k } else { c.programs.len() };
                c.programs[..upto]
                    .iter()
                    .position(|e| e.program == entry.program)
                    .map(|pk| (ci, pk))
            });
            if let Some((ci, pk)) = first {
                push(
                    format!("{at}.programs[{k}].program"),
                    format!(
                        "program \"{}\" is already configured at task_classes[{ci}].programs[{pk}]; each program runs once",
                        entry.program
                    ),
                );
            }
        }
    }
    for problem in config.joystick.check() {
        let Problem { at, message } = problem.under("joystick");
        push(at, message);
    }
    for problem in config.identification.check() {
        let Problem { at, message } = problem.under("identification");
        push(at, message);
    }
    if config.timing.realtime_priority > 99 {
        push(
            "timing.realtime_priority".into(),
            format!(
                "real-time priority must be 1..=99 (or 0: do not ask), got {}",
                config.timing.realtime_priority
            ),
        );
    }
    if config.timing.spin_us > 1000 {
        push(
            "timing.spin_us".into(),
            format!("spin margin must be at most 1000 µs, got {}", config.timing.spin_us),
        );
    }
    issues
}
